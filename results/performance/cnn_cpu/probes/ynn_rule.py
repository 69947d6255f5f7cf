import jax, jax.numpy as jnp, re
dn = ("NHWC", "HWIO", "NHWC")
def kind(k, pad, cin=64, cout=64, n=16, lhs_dil=(1, 1), stride=(1, 1)):
    f = jax.jit(lambda x, w: jax.lax.conv_general_dilated(x, w, stride, pad, lhs_dilation=lhs_dil, dimension_numbers=dn))
    t = f.lower(jnp.ones((2, n, n, cin)), jnp.ones((k, k, cin, cout))).compile().as_text()
    return "ynn" if "__ynn_fusion" in t else "not-ynn"
print("2x2 pad1_1 (out>in)", kind(2, [(1, 1), (1, 1)]))
print("2x2 pad1_0 (out=in)", kind(2, [(1, 0), (1, 0)]))
print("3x3 pad1_1", kind(3, [(1, 1), (1, 1)]))
print("3x3 16->16", kind(3, [(1, 1), (1, 1)], 16, 16))
print("3x3 16->32", kind(3, [(1, 1), (1, 1)], 16, 32))
print("9x9 4->16", kind(9, [(4, 4), (4, 4)], 4, 16))
print("9x9 16->16", kind(9, [(4, 4), (4, 4)], 16, 16))
print("4x4 s2 16->32", kind(4, [(1, 1), (1, 1)], 16, 32, stride=(2, 2)))
print("lhs dilated", kind(4, [(2, 2), (2, 2)], 32, 16, lhs_dil=(2, 2)))
