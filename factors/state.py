"""Layout of the GP-EOT state vector, shared by the models, the GTSAM factors and fgloc.

A state is ``[x, y, v, a, yaw, yawrate, r_0, ..., r_{19}]``: centre (m), speed (m/s),
longitudinal acceleration (m/s^2), yaw (rad, CCW from the frame's x axis), yaw rate (rad/s),
then the star-convex contour radii (m) at angles ``2*pi*i/20`` in the vehicle frame.
"""

from __future__ import annotations

#: number of contour radii (the paper's n_theta)
N_CONTOUR: int = 20
#: number of kinematic components (CTRA)
N_KIN: int = 6
N_STATE: int = N_KIN + N_CONTOUR
#: index of each kinematic component in a state vector
X, Y, V, A, YAW, YAWRATE = range(N_KIN)
