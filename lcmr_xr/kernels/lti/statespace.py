"""The discrete-time state-space system every LTI kernel works on, and its stability checks.

``StateSpace`` is immutable (frozen dataclass, read-only arrays), so a system can be
hashed by identity and its derived matrices cached (see :mod:`.simulate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Relative tolerance when sampling periods of interconnected systems are compared.
DT_RTOL = 1e-9


def _as_matrix(x, name: str) -> np.ndarray:
    a = np.array(x, dtype=float, copy=True)
    if a.ndim == 0:
        a = a.reshape(1, 1)
    if a.ndim != 2:
        raise ValueError(f"state-space matrix {name} must be 2-d, got shape {a.shape}.")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"state-space matrix {name} contains NaN or inf; check the model data.")
    a.setflags(write=False)  # the dataclass is frozen, so are its arrays
    return a


@dataclass(frozen=True, eq=False)
class StateSpace:
    """Discrete-time LTI system ``x(n+1) = A x(n) + B u(n)``, ``y(n) = C x(n) + D u(n)``.

    Parameters
    ----------
    A, B, C, D : array_like
        Matrices of shapes ``(n, n)``, ``(n, nu)``, ``(ny, n)``, ``(ny, nu)``; ``n = 0`` (a
        static gain) is allowed.  They are copied and made read-only.
    dt : float
        Sampling period in s (> 0).

    Examples
    --------
    >>> g = StateSpace([[0.5]], [[1.0]], [[1.0]], [[0.0]], dt=0.1)
    >>> g.n_states, g.n_inputs, g.n_outputs
    (1, 1, 1)
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float

    def __post_init__(self):
        d = _as_matrix(self.D, "D")
        ny, nu = d.shape
        n = int(np.shape(self.A)[0]) if np.size(self.A) else 0
        expected = {"A": (n, n), "B": (n, nu), "C": (ny, n), "D": (ny, nu)}
        for name, shape in expected.items():
            raw = getattr(self, name)
            # empty blocks of a static gain may come as [] or with any zero-size shape
            mat = np.zeros(shape) if np.size(raw) == 0 and 0 in shape else _as_matrix(raw, name)
            if mat.shape != shape:
                raise ValueError(
                    f"state-space matrix {name} has shape {mat.shape}, expected {shape} "
                    f"for {n} states, {nu} inputs and {ny} outputs (from A and D)."
                )
            mat.setflags(write=False)
            object.__setattr__(self, name, mat)
        dt = float(self.dt)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive sampling period in s, got {self.dt!r}.")
        object.__setattr__(self, "dt", dt)

    @property
    def n_states(self) -> int:
        """Number of states ``n``."""
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        """Number of inputs ``nu``."""
        return self.D.shape[1]

    @property
    def n_outputs(self) -> int:
        """Number of outputs ``ny``."""
        return self.D.shape[0]


def static_gain(gain, dt: float) -> StateSpace:
    """A memoryless system ``y(n) = gain u(n)`` (zero states).

    Parameters
    ----------
    gain : array_like, shape (ny, nu) or scalar
        The gain matrix.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace

    Examples
    --------
    >>> static_gain(2.0, dt=1.0).D
    array([[2.]])
    """
    d = np.atleast_2d(np.asarray(gain, dtype=float))
    ny, nu = d.shape
    return StateSpace(np.zeros((0, 0)), np.zeros((0, nu)), np.zeros((ny, 0)), d, dt)


def same_period(dt_a: float, dt_b: float) -> bool:
    """Whether two sampling periods (s) are equal up to :data:`DT_RTOL` (rounding of ``F Th``)."""
    return bool(np.isclose(dt_a, dt_b, rtol=DT_RTOL, atol=0))


def spectral_radius(A) -> float:
    """Largest ``|eigenvalue|`` of a square matrix (0 for an empty one).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix.

    Returns
    -------
    float
        ``max |eig(A)|``; a discrete system is stable when it is below 1.

    Examples
    --------
    >>> spectral_radius([[0.5, 1.0], [0.0, -0.9]])
    0.9
    """
    a = np.asarray(A, dtype=float)
    if a.size == 0:
        return 0.0
    return float(np.max(np.abs(np.linalg.eigvals(a))))


def check_stable(sys: StateSpace, what: str = "system", hint: str = "") -> float:
    """Refuse an unstable discrete-time system; return its spectral radius.

    Parameters
    ----------
    sys : StateSpace
        The system to check.
    what : str, optional
        Name used in the error message; default ``"system"``.
    hint : str, optional
        What to check, appended to the error message.

    Returns
    -------
    float
        The spectral radius of ``sys.A`` (< 1).

    Raises
    ------
    ValueError
        If the spectral radius is 1 or larger (marginally stable counts as unstable:
        a simulation would drift without bound).

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> check_stable(tf_q_inverse([1.0], [1.0, -0.5], dt=1.0))
    0.5
    """
    rho = spectral_radius(sys.A)
    if not rho < 1.0:
        raise ValueError(
            f"the {what} is unstable: its state matrix has largest |eigenvalue| {rho:.6g} >= 1."
            + (f" {hint}" if hint else "")
        )
    return rho
