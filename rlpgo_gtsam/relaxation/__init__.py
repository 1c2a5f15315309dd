"""The synchronization relaxation of a pose graph's rotations, with an optimality
certificate (SE-Sync; in the plane, CPL-SLAM's complex form), for planar and spatial graphs
alike.

The entry points take either dimension (``pose_graph.dimension``) and rotations in the
group's form: planar angles (n,), spatial matrices (n, 3, 3).

- :func:`synchronize`: the relaxation solved by the Riemannian staircase from the chordal
  estimate, rounded, polished where the staircase climbed; the rotations and their
  :class:`Certificate`.
- :func:`certify`: the certificate of given rotations, no optimization.
- :func:`relaxation_cost`: the relaxation's cost of given rotations.
- :func:`descend`: the chordal estimate moved downhill at the lowest rank, no proof.

Modules: :mod:`~rlpgo_gtsam.relaxation.staircase` (the driver),
:mod:`~rlpgo_gtsam.relaxation.trust_region`, :mod:`~rlpgo_gtsam.relaxation.verification`,
:mod:`~rlpgo_gtsam.relaxation.certificate` (:class:`Certificate`, :class:`Status`),
:mod:`~rlpgo_gtsam.relaxation.problem` (what a dimension gives the driver), and the two
problems: :mod:`~rlpgo_gtsam.relaxation.circles` (planar) and
:mod:`~rlpgo_gtsam.relaxation.stiefel` (spatial, with :mod:`~rlpgo_gtsam.relaxation.blocks`
and :mod:`~rlpgo_gtsam.relaxation.newton`), each imported when a graph of its dimension
first needs it.
"""

from rlpgo_gtsam.relaxation.certificate import Certificate, Status
from rlpgo_gtsam.relaxation.staircase import certify, descend, relaxation_cost, synchronize

__all__ = ["synchronize", "certify", "relaxation_cost", "descend", "Certificate", "Status"]
