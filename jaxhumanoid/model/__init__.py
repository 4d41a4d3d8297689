"""Physics of a planar serial chain of n links on a steady foot (Sec. II-A, II-C, II-D, II-E);
the paper's 5-link humanoid is ``PlanarChain.humanoid()``.

Conventions used throughout (Fig. 1 of the paper, stated once here):

* The plane is (x, y), y up, ground at y = 0. The body faces -x: the toes are at
  x = -a0f and the heel at x = +a0b relative to the ankle O_0 = (0, ankle_height).
* ``q`` are relative joint angles, positive counter-clockwise. The absolute angle of link l,
  measured from the +x axis, is theta_l = q_1 + ... + q_l (so q_1 is the absolute angle of the
  lower leg; standing upright is theta = pi/2 for legs and trunk).
* ``u_j`` is the torque that link j-1 (the foot, for j = 1) applies to link j, positive
  counter-clockwise. With this convention the steady-foot bound (5c) reads
  -a0f f_n0 <= u_1 <= a0b f_n0, exactly as in the paper.
* Joints O_1..O_n are named by ``PlanarChain.names`` (the humanoid: knee, hip, shoulder,
  elbow, hand); contact i acts at O_i, i = 1..n.
"""

from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain

__all__ = ["ContactParams", "FootParams", "PlanarChain"]
