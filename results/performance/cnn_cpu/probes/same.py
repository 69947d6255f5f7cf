"""Check: the torch networks of benchmarks/cnn_cpu.py compute the project's function (weights copied)."""
import sys
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import numpy as np, torch, jax, jax.numpy as jnp
from flax import nnx
import cnn_cpu
from kosmos_jax.baselines.grconvnet import GRConvNet
from kosmos_jax.baselines.ggcnn2 import GGCNN2
from kosmos_jax.baselines.transpose import ConvTranspose

def jax_layers(net):
    if isinstance(net, GRConvNet):
        names = ["conv1", "bn1", "conv2", "bn2", "conv3", "bn3"]
        mods = [getattr(net, n) for n in names]
        for b in net.residual:
            mods += [b.conv1, b.bn1, b.conv2, b.bn2]
        mods += [net.up1, net.bn4, net.up2, net.bn5, net.up3, net.heads.maps]
    else:
        mods = [net.conv1, net.conv2, net.conv3, net.conv4, net.dilated1, net.dilated2, net.up1, net.up2, net.heads.maps]
    return [(type(m).__name__, m) for m in mods]

def copy(jnet, tnet):
    tl = [m for m in tnet.modules() if isinstance(m, (torch.nn.Conv2d, torch.nn.ConvTranspose2d, torch.nn.BatchNorm2d))]
    jl = jax_layers(jnet)
    assert len(tl) == len(jl), (len(tl), len(jl))
    for (path, j), t in zip(jl, tl):
        if isinstance(j, nnx.Conv):
            t.weight.data = torch.from_numpy(np.asarray(j.kernel[...]).transpose(3, 2, 0, 1).copy())
            t.bias.data = torch.from_numpy(np.asarray(j.bias[...]).copy())
        elif isinstance(j, ConvTranspose):
            assert isinstance(t, torch.nn.ConvTranspose2d), path
            t.weight.data = torch.from_numpy(np.asarray(j.kernel[...]).transpose(2, 3, 0, 1).copy())
            t.bias.data = torch.from_numpy(np.asarray(j.bias[...]).copy())
        else:
            t.weight.data = torch.from_numpy(np.asarray(j.scale[...]).copy())
            t.bias.data = torch.from_numpy(np.asarray(j.bias[...]).copy())
    return [p for p, _ in jl]

for name, jnet, tnet, c in [("grconvnet", GRConvNet(4, 16, rngs=nnx.Rngs(0)), cnn_cpu.torch_grconvnet(torch, 4), 4),
                            ("ggcnn2", GGCNN2(1, rngs=nnx.Rngs(0)), cnn_cpu.torch_ggcnn2(torch, 1), 1)]:
    copy(jnet, tnet)
    x = np.random.default_rng(0).uniform(-0.5, 0.5, (2, 224, 224, c)).astype(np.float32)
    y = np.stack(jnet(jnp.asarray(x)), axis=1)
    with torch.no_grad():
        t = tnet.train()(torch.from_numpy(x.transpose(0, 3, 1, 2).copy())).numpy()
    print(name, y.shape, t.shape, "max abs diff", float(np.abs(y - t).max()), "max abs", float(np.abs(y).max()))
