"""The angle study's window probe (a research script kept as the record of its figures, not a tool):
can a small network read the grasp angle from a 42 px window (of the 112 px view) centred on the
target grasp, trained on a built dataset's training views and scored on its test views (share within
30 degrees)?

    python results/angle_study/window_probe/window_probe.py DATASET_DIR {conv,patch} STEPS [WINDOW] [KERNEL_BINS]

conv: three 3x3 convolutions; patch: a 14 px linear patchify and two pre-LN attention + MLP blocks
(the demo tower's pieces). Without KERNEL_BINS (or -1) it regresses (cos 2theta, sin 2theta); with
KERNEL_BINS >= 0 it is a 256-way cross-entropy against the angle tokens' start codes (0: the default
kernel, else model.angle_code_bins). Logs every 125 steps (the conv log was made when it logged
every 250)."""
import sys, time, numpy as np, jax, jax.numpy as jnp, optax, cv2
from flax import nnx
from kosmos_jax.dataset.tfds_builders import open_splits
D=sys.argv[1]; arch=sys.argv[2]; steps=int(sys.argv[3]); W=int(sys.argv[4]) if len(sys.argv)>4 else 42
s=open_splits(D)
def windows(split, n=None):
    X=[];Y=[]
    tr=s[split]
    idx=range(len(tr)) if n is None else range(min(n,len(tr)))
    for i in idx:
        r=tr.examples[i]
        g=np.asarray(r['grasp'],np.float32)
        img=s[split].images[int(r['image_index'])]
        img=cv2.resize(img,(112,112),interpolation=cv2.INTER_AREA)
        cx,cy=g[0]/2,g[1]/2
        pad=np.pad(img,((W,W),(W,W),(0,0)),mode='edge')
        x0=int(round(cx))+W-W//2; y0=int(round(cy))+W-W//2
        X.append(pad[y0:y0+W,x0:x0+W]); Y.append(g[4])
    return np.stack(X).astype(np.float32)/127.5-1, np.array(Y,np.float32)
t=time.time()
Xtr,Ytr=windows('train'); Xte,Yte=windows('test')
print('data',Xtr.shape,Xte.shape,round(time.time()-t,1),'s',flush=True)
class Conv(nnx.Module):
    def __init__(s,r):
        s.c1=nnx.Conv(3,32,(3,3),strides=1,rngs=r); s.c2=nnx.Conv(32,64,(3,3),strides=2,rngs=r); s.c3=nnx.Conv(64,128,(3,3),strides=2,rngs=r)
        s.o=nnx.Linear(128,2,rngs=r)
    def __call__(s,x):
        x=jax.nn.gelu(s.c1(x)); x=jax.nn.gelu(s.c2(x)); x=jax.nn.gelu(s.c3(x)); return s.o(x.mean((1,2)))
class Patch(nnx.Module):  # ViT-like: 14px linear patchify then 2 MLP-mixer-free token MLPs + mean
    def __init__(s,r):
        s.p=nnx.Conv(3,128,(14,14),strides=14,padding='VALID',rngs=r); s.m1=nnx.Linear(128,512,rngs=r); s.m2=nnx.Linear(512,128,rngs=r)
        s.a=nnx.MultiHeadAttention(4,128,decode=False,rngs=r); s.o=nnx.Linear(128,2,rngs=r); s.n=nnx.LayerNorm(128,rngs=r); s.n2=nnx.LayerNorm(128,rngs=r)
    def __call__(s,x):
        x=s.p(x); b=x.shape[0]; x=x.reshape(b,-1,128)
        for _ in range(2):
            x=x+s.a(s.n(x)); x=x+s.m2(jax.nn.gelu(s.m1(s.n2(x))))
        return s.o(x.mean(1))
kb=float(sys.argv[5]) if len(sys.argv)>5 else -1
from kosmos_jax.models import value_embeddings as ve
if kb>=0:
    rows=jnp.asarray(2*ve.value_code(np.arange(256)*2*np.pi/256,128,None if kb==0 else ve.angle_harmonic_width(kb)),jnp.float32)
    class Head(nnx.Module):
        def __init__(s,r): s.b=Patch(r); s.b.o=nnx.Linear(128,128,rngs=r)
        def __call__(s,x): return s.b(x)@rows.T
    model=Head(nnx.Rngs(0))
else:
    model={'conv':Conv,'patch':Patch}[arch](nnx.Rngs(0))
opt=nnx.Optimizer(model,optax.adamw(optax.warmup_cosine_decay_schedule(0,1e-3,50,steps)),wrt=nnx.Param)
def target(y): return jnp.stack([jnp.cos(2*y),jnp.sin(2*y)],-1)
@nnx.jit
def step(model,opt,x,y):
    def lf(m):
        if kb>=0:
            t=jnp.floor((y+np.pi/2)/np.pi*256).astype(jnp.int32)%256
            return -jnp.take_along_axis(jax.nn.log_softmax(m(x)),t[:,None],1).mean()
        return ((m(x)-target(y))**2).sum(-1).mean()
    l,g=nnx.value_and_grad(lf)(model); opt.update(model,g); return l
@nnx.jit
def pred(model,x):
    o=model(x)
    if kb>=0: return (jnp.argmax(o,-1)+0.5)/256*np.pi-np.pi/2
    return jnp.arctan2(o[:,1],o[:,0])/2
def acc(X,Y):
    p=np.concatenate([np.asarray(pred(model,X[i:i+256])) for i in range(0,len(X),256)])
    d=np.abs(((p-Y)+np.pi/2)%np.pi-np.pi/2); return round(float((d<np.pi/6).mean()*100),1)
rng=np.random.default_rng(0); t=time.time()
for i in range(steps):
    b=rng.integers(0,len(Xtr),64)
    l=step(model,opt,jnp.asarray(Xtr[b]),jnp.asarray(Ytr[b]))
    if (i+1)%125==0: print(arch,i+1,round(float(l),3),'train',acc(Xtr[:1000],Ytr[:1000]),'test',acc(Xte,Yte),round(time.time()-t),'s',flush=True)
