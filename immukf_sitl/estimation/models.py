"""What a filter needs to know about a system: process and measurement models.

Every function takes the component axis first and any batch axes after it (see
``docs/conventions.md``): a state ``x`` of shape ``(nx, *batch)`` and noise of shape
``(nv, *batch)``; the control ``u`` is passed through untouched. The argument order is always
``(t_s, x, u, noise)``: a filter step from ``t_k`` to ``t_k+1`` calls ``f`` with ``t_k`` (the
start of the step it integrates) and ``g`` with ``t_k+1`` (the time of the measurement). The
model is noise-free in the sense that the *filter* chooses the noise samples (augmented form)
or passes ``None`` and adds the covariance (additive form).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.estimation.symmetry import StateSymmetry

#: ``f(t_s, x, u, v) -> x_next`` (eq. 1) from ``t_s``, the start of the step; ``v`` is ``None``
#: in the additive-noise form.
ProcessFn = Callable[[float, np.ndarray, np.ndarray, "np.ndarray | None"], np.ndarray]
#: ``g(t_s, x, u, w) -> z`` (eq. 2) at ``t_s``, the time of the measurement; ``w`` is ``None`` in
#: the additive-noise form.
MeasurementFn = Callable[[float, np.ndarray, np.ndarray, "np.ndarray | None"], np.ndarray]


def psd_sqrt(matrix: np.ndarray) -> np.ndarray:
    """A square root ``L`` with ``L L' = M`` of a constant symmetric PSD matrix.

    Lower Cholesky factor when it exists; otherwise ``V sqrt(max(D, 0))`` from ``eigh``, which
    also serves a singular noise covariance (e.g. ``G Q G'`` of rank below ``n``).
    """
    matrix = np.asarray(matrix, dtype=float)
    try:
        return np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        eigval, eigvec = np.linalg.eigh(0.5 * (matrix + matrix.T))
        if eigval.min() < -1e-9 * max(1.0, float(np.abs(eigval).max())):
            raise ValueError("noise covariance is not positive semi-definite") from None
        return eigvec * np.sqrt(np.clip(eigval, 0.0, None))


def _checked_cov(name: str, cov: np.ndarray) -> np.ndarray:
    cov = np.array(cov, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {cov.shape}")
    if not np.allclose(cov, cov.T, rtol=1e-12, atol=1e-15):
        raise ValueError(f"{name} must be symmetric")
    cov.setflags(write=False)
    return cov


@dataclass(frozen=True)
class ProcessModel:
    """State equation ``x(k+1) = f[x(k), u(k), v(k)]`` (eq. 1) and its noise.

    Parameters
    ----------
    f : ProcessFn
        ``f(t_s, x, u, v)``; with ``v=None`` it must behave as ``v = 0``.
    nx : int
        State dimension.
    noise_cov : ndarray, shape (nv, nv)
        ``Q``, the covariance of ``v`` (augmented form).
    additive_noise_cov : ndarray, shape (nx, nx), optional
        Covariance added to the predicted state covariance by the additive-noise form
        (``G Q G'`` for a noise gain ``G``). Required only for that form.
    angle_idx : tuple of int
        State components that are angles (wrapped residuals, circular means).
    state_noise_cov : ndarray, shape (nx, nx), optional
        Driving noise of slowly varying states that ``f`` does not take through ``v`` (random
        walks, Gauss-Markov processes, linear in the state), referred to the start of the step:
        the augmented form adds it to ``P(k|k)`` before drawing the sigma points, so that it
        reaches the update's cross-covariances as well as ``P(k+1|k)``. For
        ``x(k+1) = a x(k) + w``, ``Var w = q``, it is ``q / a^2``. The additive form's
        ``additive_noise_cov`` must hold the same noise referred to the step's end (``q``).
    consider_idx : tuple of int
        Consider states (Schmidt-Kalman): their uncertainty enters every prediction and gain
        of the others, but no measurement moves their mean or shrinks their own covariance
        (their rows of the gain are zero). For nuisance states the data cannot separate from
        others, e.g. a GPS receiver's slowly wandering error beside the position.
    symmetry : StateSymmetry, optional
        A symmetry of ``f`` the measurements do not observe: each update carries the
        covariance along it to the updated mean (:mod:`immukf_sitl.estimation.symmetry`).
    """

    f: ProcessFn
    nx: int
    noise_cov: np.ndarray
    additive_noise_cov: np.ndarray | None = None
    angle_idx: tuple[int, ...] = ()
    state_noise_cov: np.ndarray | None = None
    consider_idx: tuple[int, ...] = ()
    symmetry: StateSymmetry | None = None
    noise_sqrt: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise_cov", _checked_cov("noise_cov", self.noise_cov))
        object.__setattr__(self, "noise_sqrt", psd_sqrt(self.noise_cov))
        for name in ("additive_noise_cov", "state_noise_cov"):
            value = getattr(self, name)
            if value is not None:
                cov = _checked_cov(name, value)
                if cov.shape != (self.nx, self.nx):
                    raise ValueError(f"{name} must be ({self.nx}, {self.nx})")
                object.__setattr__(self, name, cov)
        consider = tuple(int(i) for i in self.consider_idx)
        if any(not 0 <= i < self.nx for i in consider) or len(set(consider)) != len(consider):
            raise ValueError(f"consider_idx must be distinct states of 0..{self.nx - 1}")
        object.__setattr__(self, "consider_idx", consider)

    @property
    def nv(self) -> int:
        """Process-noise dimension."""
        return self.noise_cov.shape[0]


@dataclass(frozen=True)
class MeasurementModel:
    """Output equation ``z = g[x, u, w]`` (eq. 2) and its noise ``w ~ N(0, R)``.

    Parameters
    ----------
    g : MeasurementFn
        ``g(t_s, x, u, w)``; with ``w=None`` it must behave as ``w = 0``. For a bank of
        mode-matched filters ``x`` arrives as ``(nx, modes, sigma)`` and ``g`` may depend on the
        mode axis (see :func:`immukf_sitl.estimation.fault_modes.fault_mode_output`).
    noise_cov : ndarray, shape (nz, nz)
        ``R``.
    angle_idx : tuple of int
        Output components that are angles.
    name : str
        For messages and diagnostics.
    mode_noise_var : ndarray, shape (modes, nz), optional
        Variance each filter of a bank adds to each output channel on top of ``R`` (a fault
        mode's width on its failed channels, :func:`~immukf_sitl.estimation.fault_modes.
        fault_mode_noise_var`); None: nothing.
    """

    g: MeasurementFn
    noise_cov: np.ndarray
    angle_idx: tuple[int, ...] = ()
    name: str = "measurement"
    mode_noise_var: np.ndarray | None = None
    noise_sqrt: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise_cov", _checked_cov("noise_cov", self.noise_cov))
        object.__setattr__(self, "noise_sqrt", psd_sqrt(self.noise_cov))
        if self.mode_noise_var is not None:
            var = np.array(self.mode_noise_var, dtype=float)
            if var.ndim != 2 or var.shape[1] != self.nz or not np.all(var >= 0.0):
                raise ValueError(
                    f"mode_noise_var: expected non-negative variances of shape (modes, {self.nz}),"
                    f" got shape {var.shape}"
                )
            var.setflags(write=False)
            object.__setattr__(self, "mode_noise_var", var)

    def added_cov(self, batch: int, additive: bool) -> np.ndarray:
        """``(batch, nz, nz)``: what each filter adds to its ``P_zz`` (``R`` when ``additive``)."""
        base = self.noise_cov if additive else np.zeros((self.nz, self.nz))
        out = np.repeat(base[None], batch, axis=0)
        if self.mode_noise_var is not None:
            if self.mode_noise_var.shape[0] != batch:
                raise ValueError(
                    f"{self.name}: mode_noise_var has {self.mode_noise_var.shape[0]} modes, "
                    f"the bank {batch}"
                )
            idx = np.arange(self.nz)
            out[:, idx, idx] += self.mode_noise_var
        return out

    @property
    def nz(self) -> int:
        """Output dimension."""
        return self.noise_cov.shape[0]


@dataclass(frozen=True)
class SampleGate:
    """What some filters will not read of a sample, decided once their predictions are known.

    ``widths(innovation, variance)`` gets the innovation (eq. 21) of each ``(filter, output)``
    pair and its variance (the diagonal of eq. 20), ``(k,)`` each, and returns the variance to
    add to each pair at this sample, ``(k,)``: an outlier a filter keeps out of its update.
    """

    filters: np.ndarray
    outputs: np.ndarray
    widths: Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Measurement:
    """One observation ``z(k+1)`` and the model that explains it."""

    z: np.ndarray
    model: MeasurementModel
    #: ``(batch, nz)``: variance each filter adds to each channel at this step only (e.g. a
    #: fault mode's width on a channel it believes dead or stuck); None: nothing
    extra_var: np.ndarray | None = None
    #: what some filters will not read of this sample, given their innovations
    gate: SampleGate | None = None

    def __post_init__(self) -> None:
        z = np.asarray(self.z, dtype=float)
        if z.shape != (self.model.nz,):
            raise ValueError(
                f"measurement {self.model.name!r} needs shape ({self.model.nz},), got {z.shape}"
            )
        object.__setattr__(self, "z", z)
