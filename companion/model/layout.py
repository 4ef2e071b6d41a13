"""Constants shared by the derivation (``derive``) and its evaluation (``dynamics``).

The generated ``_mcg.mcg`` writes a float64 array of shape (N_XI, N_Q * ROW): one piece per
entry of xi = [m2, m3, m4, 1] (paper eq. reg), each made of N_Q rows of ROW = 17 values,
row i being ``[M_k[i, 0:8] | C_k[i, 0:8] | G_k[i]]``. Hence ``xi @ pieces`` is M, C, G for
one theta, and ``pieces.reshape(N_XI * N_Q, ROW) @ [qr_ddot; qr_dot; 1]`` is Y^T.
"""

from companion.coordinates import N_Q

N_XI = 4
"""xi = [m2, m3, m4, 1]."""
ROW = 2 * N_Q + 1
"""One row of a piece: M_k row, C_k row, G_k entry."""
XI_ORDER = (1, 2, 3, 0)
"""Pieces as coefficients of xi: the split (known, m2, m3, m4) reordered."""
PARAM_NAMES = (
    "mb", "ixx", "iyy", "izz", "m1", "s1", "j1", "a1", "a2", "l1", "rax", "ray", "raz", "g",
)  # fmt: skip
"""Known parameters, in the order of the generated functions' ``p`` argument: vehicle mass,
principal inertia, link-1 mass, first and second moment about joint 1, armatures, l1,
mount point r_a (body FLU), gravity."""
