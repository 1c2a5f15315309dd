"""The robust path's settings: every tuning constant of
:func:`~rlpgo_gtsam.robust.robust_initialize`, each with the reason for its value.

The defaults are the robust path's as measured on ``benchmarks/robust*.py`` (Vertigo's four
policies of wrong closures on the shared planar files, the generator's planar and 3D graphs,
SE-Sync's 3D files); docs/robust.md gives the figures. A field ending in ``_2d`` or ``_3d``
holds for planar or for 3D graphs only.
"""

from __future__ import annotations

from dataclasses import dataclass

from rlpgo_gtsam.errors import SolverError

__all__ = ["RobustSettings"]


@dataclass(frozen=True, kw_only=True)
class RobustSettings:
    """What the robust path decides with; the defaults are its tested behaviour."""

    # --- what counts as evidence
    inlier_probability: float = 0.9999
    """An inlier's residual lies below the chi-square quantile at this probability."""
    false_rejection_rate: float = 0.0025
    """Expected share of true closures among the false-rejection bar's rejections (0: off)."""
    rejected_below: float = 0.5
    """A GNC weight below this is a rejection: TLS weights end near 0 or 1."""
    doubtful_below: float = 0.05
    """Kept closures fitting with a p-value below this are listed: 1 in 20 true ones does."""
    gnc_iterations: int = 100
    """Outer iterations of each GNC at most (the translation step's and GTSAM's)."""

    # --- before the steps
    reach_margin: float = 10.0
    """Edges beyond this times the others' summed reach are out (1 is proof; the margin is the
    steps' room: they judge what merely conflicts)."""

    # --- step 0, all edges
    all_edges_iterations: int = 25
    """Relaxation iterations: clean shared files certify within 19; wrong closures cost more."""
    max_noise_scale: float = 1000.0
    """Odometry noise up to this times its stated variance is noise (noisy files: ~110x)."""
    noise_conflicts: float = 0.5
    """From this share of conflicting pairs the cycles contradict the stated noise itself."""

    # --- step 1, pairwise consistency
    consistency_near: int = 16
    """Closures tested per closure next to it in chain order: local evidence."""
    consistency_far: int = 16
    """Closures tested per closure spread over the chain: global evidence, long cycles."""
    consistency_chunk: int = 50_000
    """Pairs scored at once: memory stays bounded whatever the closures' layout."""
    support_window: int = 15
    """Chain steps within which a cycle is short: over long ones anything agrees."""
    loose_support: int = 3
    """Agreements over short cycles that give a closure loose support (a seed closure)."""
    min_support: int = 3
    """Informative agreements that give support: 3 of 32 tests pass by chance 0.4% of wrong."""
    informative_chance: float = 0.01
    """A test is informative where a wrong closure passes it less often than this."""
    data_scale: float = 40.0
    """A pair agrees below this times the scores' lower quartile if lower (loose data)."""
    conflict_scale: float = 200.0
    """A pair conflicts above this times the lower quartile if lower: 6e-6 of true pairs do."""
    ambiguous_ratio: float = 0.8
    """An alternative this large against the kept side is reported ambiguous, not hidden."""

    # --- step 2, start
    start_iterations: int = 25
    """Relaxation iterations of the seed: its rotations only start the translation step."""

    # --- step 3, verify
    verify_rounds: int = 60
    """Rounds at most: refuted true closures come back a tier a round (20 were too few)."""
    round_iterations: int = 5
    """Solver iterations a round: it needs the map's shape, not convergence."""
    round_tolerance: float = 0.0001
    """Relative chi2 change that ends a round's solve: its bars are 21 and up."""
    samples: int = 64
    """Draws estimating a residual covariance: relative error about sqrt(2 / 64)."""
    draw_seed: int = 0
    """Seed of those draws: the same graph gives the same decision."""
    solve_block: int = 8
    """Draws solved per SuperLU call: the fastest on MIT, FR079 and M3500."""
    leverage_floor: float = 0.001
    """Residual covariance eigenvalues are held above this."""
    leverage_check: float = 0.1
    """Kept sets of a residual spread below this hold their stretch: solved without."""
    held_checks: int = 4
    """Solves without a holding set per verify call, at most."""
    tight: float = 2.0
    """Closures the map checks with an innovation spread up to this come in at once."""
    admit_chance: float = 0.001
    """So do those a wrong closure would pass less often than this."""
    linear_rad: float = 1.0
    """A closure the map must turn more than this (radians) to fit is judged by a solve."""
    run_reach: int = 2
    """Parallel closures this many poses apart or closer form a run (or a cluster)."""
    run_max: int = 5
    """Runs and clusters are judged in pieces of at most this many (Vertigo's group size)."""
    cluster_window: int = 40
    """Closures after each (by low end) it may link to: a round stays linear in closures."""

    # --- step 3, exchanges of exclusive sets
    exchange_tries: int = 1
    """Suspects questioned per verify call, at most: each costs two solves."""
    exchange_reach: int = 20
    """Poses: closures this near a suspect are its rivals (Vertigo's local policy's reach)."""
    exchange_misfit: float = 10.0
    """Bars: rivals that misfit by more do not count ..."""
    exchange_nearest: float = 3.0
    """... and the nearest must misfit by less, or the question finds nothing."""

    # --- step 3, restarts from the kept edges' relaxation
    warm_iterations: int = 20
    """Relaxation iterations from the map at hand."""
    restart_iterations: int = 30
    """The kept edges' relaxation is refined this far: enough to tell its basin."""
    restarts: int = 3
    """Verify runs again from the kept edges' relaxation at most this many times ..."""
    same_basin_rad: float = 0.25
    """... where it turns some pose this much (radians): within a basin, 0.1 rad at most ..."""
    restart_gain: float = 1e-6
    """... and its chi2 lies this much lower (relative): each can find a lower basin."""

    # --- what differs between planar and 3D graphs
    skip_conflicts_2d: float | None = 0.01
    """Planar: the all-edges step is skipped from this share of conflicting pairs (clean: 0.17%)."""
    skip_conflicts_3d: float | None = None
    """3D: never skipped; clean files conflict more (1.7%) than corrupted ones (from 0.4%)."""
    relaxed_start_2d: bool = True
    """Planar rounds start from the kept edges' relaxation: dropped closures bent the seed."""
    relaxed_start_3d: bool = False
    """3D rounds start from the start's map: from the relaxation true closures stayed out."""
    admit_tier_2d: float = 10.0
    """Planar rounds also admit closures within this times the tightest spread (100: too many)."""
    admit_tier_3d: float = 2.0
    """3D rounds also admit closures within this times the tightest spread."""
    hotelling_runs_2d: bool = False
    """Planar runs are judged by chi-square's quantile: at 15 dof close to their own bar."""
    hotelling_runs_3d: bool = True
    """3D runs by their own tail: at 30 dof a true run passes chi-square's only 99.3%."""
    relaxation_iterations_3d: int = 20
    """3D relaxations stop at rank 3 after this many iterations: clean files certify in 8."""

    # --- solves
    lm_iterations: int = 100
    """LM iterations of a solve run to convergence."""
    tolerance: float = 1e-10
    """Relative error tolerance of a solve run to convergence (the project's)."""
    anchor_sigma: float = 1e-8
    """Sigma of GNC-LM's gauge prior: the anchor keeps its pose."""

    def __post_init__(self) -> None:
        if not 0.0 < self.inlier_probability < 1.0:
            raise SolverError(
                f"inlier_probability must lie in (0, 1), got {self.inlier_probability}")
        if self.gnc_iterations < 1:
            raise SolverError(f"gnc_iterations must be >= 1, got {self.gnc_iterations}")
        if not self.reach_margin >= 1.0:
            raise SolverError(f"reach_margin must be at least 1, got {self.reach_margin}")
        if not 0.0 <= self.false_rejection_rate < 1.0:
            raise SolverError(
                f"false_rejection_rate must lie in [0, 1), got {self.false_rejection_rate}")

    def skip_conflicts(self, dimension: int) -> float | None:
        """``skip_conflicts_2d`` or ``skip_conflicts_3d``."""
        return self.skip_conflicts_3d if dimension == 3 else self.skip_conflicts_2d

    def relaxed_start(self, dimension: int) -> bool:
        """``relaxed_start_2d`` or ``relaxed_start_3d``."""
        return self.relaxed_start_3d if dimension == 3 else self.relaxed_start_2d

    def admit_tier(self, dimension: int) -> float:
        """``admit_tier_2d`` or ``admit_tier_3d``."""
        return self.admit_tier_3d if dimension == 3 else self.admit_tier_2d

    def hotelling_runs(self, dimension: int) -> bool:
        """``hotelling_runs_2d`` or ``hotelling_runs_3d``."""
        return self.hotelling_runs_3d if dimension == 3 else self.hotelling_runs_2d
