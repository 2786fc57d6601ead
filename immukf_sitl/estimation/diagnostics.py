"""Counters of every numerical safeguard, readable by the caller.

Repairs are never silent: each one increments a named counter here, and the service reports them
in its stats line.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class FilterDiagnostics:
    """Running counts of the safeguards a filter applied.

    Attributes
    ----------
    steps : int
        Filter steps run (one per call, whatever the batch size).
    symmetrised : int
        Covariances symmetrised (every covariance, every step: ``P = (P + P') / 2``).
    cholesky_jitter : int
        State or innovation covariances that failed Cholesky and were repaired by adding a
        diagonal jitter.
    cholesky_eigen_floor : int
        Covariances that still failed after jitter and were repaired by flooring eigenvalues.
    skipped_nonfinite_measurement : int
        Updates skipped because the measurement held a NaN or an infinity (predict only).
    outlier_innovations : int
        Mode-matched innovations whose normalised squared size (NIS) exceeded the outlier gate;
        they are still used (the IMM needs their low likelihood) but counted.
    nonfinite_state_reset : int
        Mode-matched estimates that became non-finite and were reset to the mixed prior.
    indefinite_state_reset : int
        Mode-matched estimates whose updated covariance had a negative variance (the update
        of a filter far from its measurement) and were reset to the mixed prior.
    """

    steps: int = 0
    symmetrised: int = 0
    cholesky_jitter: int = 0
    cholesky_eigen_floor: int = 0
    skipped_nonfinite_measurement: int = 0
    outlier_innovations: int = 0
    nonfinite_state_reset: int = 0
    indefinite_state_reset: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dictionary (for JSON and stats lines)."""
        return asdict(self)
