"""The ranges a robot's numbers may take, whatever the robot comes from (a parameter set or a
URDF): every model the engine builds is within them, and the API's schemas declare the same
numbers (``service.schemas.common``), so a robot is accepted or refused alike by either door.

They rule out overflow: within them every product the kinematics and dynamics form is finite.
SI units."""

from __future__ import annotations

#: Joints (and moving links) of a model.
MAX_JOINTS = 12
#: kg, any body's mass.
MAX_MASS_KG = 1e9
#: m, any vector of a model (``a``, ``b``), and positions in tasks.
MAX_LENGTH_M = 1e3
#: kg m^2, any component of an inertia tensor.
MAX_INERTIA = 1e12
#: N m or N, a joint's effort limit (torque or force).
MAX_EFFORT = 1e6
#: rad or m, a joint's position limits.
MAX_JOINT_LIMIT = 1e6
#: ``<link>`` (and ``<joint>``) elements a URDF may have, counted before the tree is walked.
MAX_URDF_LINKS = 1000
