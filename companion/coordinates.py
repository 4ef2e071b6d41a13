"""Names for the rows of the generalized coordinates (DESIGN.md section 2).

q = [x, y, z, phi, theta, psi, eta1, eta2]: vehicle position, world ENU [m]; ZYX Euler
angles of body FLU [rad]; joint angles [rad]. q_dot, q_ddot and the generalized force tau
share the rows (tau: world force [N], forces conjugate to the Euler angles, joint torques
[N m]). Index the state through these names, not through raw slices.
"""

N_Q = 8
"""Number of generalized coordinates."""
X, Y, Z, PHI, THETA, PSI, ETA1, ETA2 = range(N_Q)
"""Single rows."""
POSITION = slice(0, 3)
"""x, y, z (world ENU)."""
HORIZONTAL = slice(0, 2)
"""x, y."""
ATTITUDE = slice(3, 6)
"""phi, theta, psi (ZYX Euler)."""
TILT = slice(3, 5)
"""phi, theta: roll and pitch."""
JOINTS = slice(6, 8)
"""eta1, eta2."""
N_JOINTS = 2
"""Joints of the arm."""
