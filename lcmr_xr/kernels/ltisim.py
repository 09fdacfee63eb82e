"""Discrete-time state space, lifting of state space, and a fast multirate closed-loop simulator.

Pure numpy/scipy, no labels.  Time signals are arrays ``(..., N, channels)``: time on the
second-to-last axis, channels last, any leading axes broadcast (experiments, seeds).

Lifting follows :mod:`lcmr_xr.kernels.lifting`: a fast signal with ``c`` channels becomes a
slow signal with ``F c`` channels ordered phase-major (lifted channel ``j c + ch`` is channel
``ch`` at phase ``j``), which for ``(N, c)`` arrays is the plain reshape to ``(N/F, F c)``.

The simulator never steps sample by sample in Python.  It cuts time into blocks of ``L``
samples and uses the ``L``-lifted system: outputs of all blocks at once are one batched matmul
with the block-Toeplitz impulse-response matrix plus the observability matrix times the
block-start states, and only the block-start states follow a Python loop over ``N/L`` blocks.

The multirate closed loop (fast plant, slow controller, zero-order hold, fast filter) is
periodically time-varying at the fast rate but LTI at the slow rate once lifted; it is built
here as ONE slow-rate state-space system and simulated with the same fast simulator.
"""

from __future__ import annotations

import functools

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np
import scipy.linalg

__all__ = [
    "StateSpace",
    "MultirateClosedLoop",
    "MultirateResponse",
    "static_gain",
    "continuous_zoh",
    "modal_zoh",
    "tf_q_inverse",
    "matched_notch",
    "notch_filter",
    "series",
    "block_diagonal",
    "hstack",
    "vstack",
    "frequency_response",
    "dc_gain",
    "lift_statespace",
    "spectral_radius",
    "check_stable",
    "simulate_lti",
    "multirate_closed_loop",
    "simulate_multirate",
]

#: Relative tolerance when sampling periods of interconnected systems are compared.
_DT_RTOL = 1e-9


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


# --------------------------------------------------------------------------- discretisation


def continuous_zoh(A, B, C, D, dt: float) -> StateSpace:
    """Zero-order-hold discretisation of a continuous-time state-space system.

    Parameters
    ----------
    A, B, C, D : array_like
        Continuous-time matrices (``dx/dt = A x + B u``, ``y = C x + D u``).
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        ``Ad = exp(A dt)``, ``Bd = int_0^dt exp(A s) ds B``, same ``C`` and ``D``.

    Notes
    -----
    Computed from one matrix exponential of ``[[A, B], [0, 0]] dt``.  Keep the system
    well scaled (modal blocks rather than a companion form): the exponential of a
    high-order companion matrix loses all accuracy.

    Examples
    --------
    >>> g = continuous_zoh([[-1.0]], [[1.0]], [[1.0]], [[0.0]], dt=0.5)
    >>> bool(np.isclose(g.A[0, 0], np.exp(-0.5)))
    True
    """
    a = np.atleast_2d(np.asarray(A, dtype=float))
    b = np.atleast_2d(np.asarray(B, dtype=float))
    n, nu = b.shape
    big = np.zeros((n + nu, n + nu))
    big[:n, :n] = a * dt
    big[:n, n:] = b * dt
    e = scipy.linalg.expm(big)
    return StateSpace(e[:n, :n], e[:n, n:], C, D, dt)


def modal_zoh(gains, freqs_hz, dampings, dt: float) -> StateSpace:
    """ZOH discretisation of ``sum_i k_i / (s^2 + 2 z_i w_i s + w_i^2)``, ``w_i = 2 pi f_i``.

    Each mode is discretised on its own 2x2 block and the blocks are stacked
    block-diagonally.  A transfer function of the sum would be of high order with
    coefficients spanning hundreds of decades (``w^2 ~ 1e11`` per mode) and overflows or
    loses all precision; the modal blocks are each well conditioned.

    Parameters
    ----------
    gains : array_like, shape (K,)
        Modal gains ``k_i`` (output units per input unit times s^-2).
    freqs_hz : array_like, shape (K,)
        Natural frequencies ``f_i`` in Hz (``0`` with damping ``0`` is a rigid-body mode
        ``k/s^2``).
    dampings : array_like, shape (K,)
        Relative dampings ``z_i`` (1).
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, ``2 K`` states (``w_i q_i`` and ``dq_i/dt`` of each mode ``q_i``; plain
        position for a rigid-body mode), ``D = 0``.

    Examples
    --------
    >>> g = modal_zoh([1.0], [0.0], [0.0], dt=1.0)   # double integrator 1/s^2
    >>> g.B.ravel().tolist()
    [0.5, 1.0]
    """
    k = np.atleast_1d(np.asarray(gains, dtype=float))
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    z = np.atleast_1d(np.asarray(dampings, dtype=float))
    if not (k.shape == f.shape == z.shape) or k.ndim != 1:
        raise ValueError(
            f"gains, freqs_hz and dampings must be 1-d and of equal length, got shapes "
            f"{k.shape}, {f.shape}, {z.shape}."
        )
    blocks_a, blocks_b, c = [], [], []
    for ki, fi, zi in zip(k, f, z):
        w = 2 * np.pi * fi
        # States (w q, dq/dt) instead of (q, dq/dt): every entry of A is then of order w, so
        # the exponential is cheap and accurate and the discrete blocks are well scaled.
        scale = w if w > 0 else 1.0
        mode = continuous_zoh([[0.0, scale], [-w * w / scale, -2 * zi * w]], [[0.0], [1.0]],
                              [[ki / scale, 0.0]], [[0.0]], dt)
        blocks_a.append(mode.A)
        blocks_b.append(mode.B)
        c.append(mode.C)
    return StateSpace(scipy.linalg.block_diag(*blocks_a), np.vstack(blocks_b), np.hstack(c),
                      [[0.0]], dt)


def tf_q_inverse(num, den, dt: float) -> StateSpace:
    """SISO system from a transfer function in powers of ``q^-1``.

    ``(b0 + b1 q^-1 + ... ) / (a0 + a1 q^-1 + ...)``, realised in observable canonical form.

    Parameters
    ----------
    num, den : array_like
        Coefficients ``[b0, b1, ...]`` and ``[a0, a1, ...]``; ``a0 != 0``.  The shorter one is
        padded with zeros.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace

    Examples
    --------
    >>> g = tf_q_inverse([0.0, 1.0], [1.0, -0.5], dt=1.0)   # q^-1 / (1 - 0.5 q^-1)
    >>> float(dc_gain(g)[0, 0])
    2.0
    """
    b = np.atleast_1d(np.asarray(num, dtype=float))
    a = np.atleast_1d(np.asarray(den, dtype=float))
    if a[0] == 0:
        raise ValueError(
            f"the leading denominator coefficient a0 must be nonzero (causal system), got {a}."
        )
    n = max(a.size, b.size)
    b = np.pad(b, (0, n - b.size)) / a[0]
    a = np.pad(a, (0, n - a.size)) / a[0]
    order = n - 1
    d0 = b[0]
    if order == 0:
        return static_gain(d0, dt)
    A = np.zeros((order, order))
    A[:, 0] = -a[1:]
    A[:-1, 1:] = np.eye(order - 1)
    B = (b[1:] - a[1:] * d0).reshape(order, 1)
    C = np.zeros((1, order))
    C[0, 0] = 1.0
    return StateSpace(A, B, C, [[d0]], dt)


def matched_notch(freq_hz: float, zeta_num: float, zeta_den: float, dt: float) -> StateSpace:
    """Matched pole-zero discretisation of ``(s^2 + 2 zn w s + w^2)/(s^2 + 2 zd w s + w^2)``.

    Zeros and poles are mapped by ``z = exp(s dt)``; the gain is chosen for unit DC gain.

    Parameters
    ----------
    freq_hz : float
        Notch frequency ``f = w / (2 pi)`` in Hz (below the Nyquist frequency ``1/(2 dt)``).
    zeta_num, zeta_den : float
        Relative dampings of the zeros and of the poles (1); ``zeta_num < zeta_den`` notches.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, 2 states.

    Examples
    --------
    >>> g = matched_notch(1000.0, 0.01, 0.5, dt=1e-4)
    >>> round(float(dc_gain(g)[0, 0]), 12)
    1.0
    """
    if not 0 < freq_hz < 0.5 / dt:
        raise ValueError(
            f"notch frequency {freq_hz} Hz must lie between 0 and the Nyquist frequency "
            f"{0.5 / dt} Hz of dt={dt} s; drop the section or sample faster."
        )
    w = 2 * np.pi * freq_hz

    def mapped(zeta):
        # discrete polynomial [1, c1, c2] in z with roots exp(s_i dt) (real: roots conjugate)
        return np.real(np.poly(np.exp(np.roots([1.0, 2 * zeta * w, w * w]) * dt)))

    num, den = mapped(zeta_num), mapped(zeta_den)
    num = num * den.sum() / num.sum()  # unit gain at z = 1
    return tf_q_inverse(num, den, dt)  # z^-2 (num) / z^-2 (den) is the same ratio in q^-1


def notch_filter(sections: Sequence[tuple[float, float, float]], dt: float) -> StateSpace:
    """Cascade of :func:`matched_notch` sections ``(freq_hz, zeta_num, zeta_den)``.

    Parameters
    ----------
    sections : sequence of (float, float, float)
        Rows ``(f Hz, zn, zd)``.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, ``2 len(sections)`` states, unit DC gain.

    Examples
    --------
    >>> g = notch_filter([(1000.0, 0.01, 0.5), (2000.0, 0.01, 0.5)], dt=1e-4)
    >>> g.n_states
    4
    """
    systems = [matched_notch(f, zn, zd, dt) for f, zn, zd in sections]
    if not systems:
        return static_gain(1.0, dt)
    return series(*systems)


# --------------------------------------------------------------------------- interconnection


def _same_dt(systems: Sequence[StateSpace]) -> float:
    dt = systems[0].dt
    for s in systems[1:]:
        if not np.isclose(s.dt, dt, rtol=_DT_RTOL, atol=0):
            raise ValueError(
                f"cannot interconnect systems with sampling periods {dt} s and {s.dt} s; "
                "discretise every part at the same period (or lift the faster one)."
            )
    return dt


def series(*systems: StateSpace) -> StateSpace:
    """Cascade in signal-flow order: ``series(G1, G2)`` is ``u -> G1 -> G2 -> y`` (``G2 G1``).

    Parameters
    ----------
    *systems : StateSpace
        At least one; outputs of each must match inputs of the next.

    Returns
    -------
    StateSpace
        States ordered ``[x1, x2, ...]``.

    Examples
    --------
    >>> g = series(static_gain(2.0, 1.0), static_gain(3.0, 1.0))
    >>> float(g.D[0, 0])
    6.0
    """
    if not systems:
        raise ValueError("series needs at least one system.")
    dt = _same_dt(systems)
    out = systems[0]
    for g in systems[1:]:
        if g.n_inputs != out.n_outputs:
            raise ValueError(
                f"series: a system with {out.n_outputs} outputs cannot feed one with "
                f"{g.n_inputs} inputs; check the order (signal flow, first system first)."
            )
        n1, n2 = out.n_states, g.n_states
        A = np.block([[out.A, np.zeros((n1, n2))], [g.B @ out.C, g.A]])
        B = np.vstack([out.B, g.B @ out.D])
        C = np.hstack([g.D @ out.C, g.C])
        out = StateSpace(A, B, C, g.D @ out.D, dt)
    return out


def block_diagonal(*systems: StateSpace) -> StateSpace:
    """Systems side by side: inputs and outputs stacked, no coupling.

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same ``dt``.

    Returns
    -------
    StateSpace

    Examples
    --------
    >>> block_diagonal(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """
    if not systems:
        raise ValueError("block_diagonal needs at least one system.")
    dt = _same_dt(systems)
    bd = scipy.linalg.block_diag
    return StateSpace(bd(*[s.A for s in systems]), bd(*[s.B for s in systems]),
                      bd(*[s.C for s in systems]), bd(*[s.D for s in systems]), dt)


def hstack(*systems: StateSpace) -> StateSpace:
    """``y = G1 u1 + G2 u2 + ...``: inputs concatenated, outputs summed (e.g. ``[Pv, Pp]``).

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same number of outputs and the same ``dt``.

    Returns
    -------
    StateSpace
        States stacked in argument order.

    Examples
    --------
    >>> hstack(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0, 2.0]]
    """
    g = block_diagonal(*systems)
    ny = systems[0].n_outputs
    if any(s.n_outputs != ny for s in systems):
        raise ValueError("hstack: every system must have the same number of outputs.")
    summer = np.hstack([np.eye(ny)] * len(systems))
    return StateSpace(g.A, g.B, summer @ g.C, summer @ g.D, g.dt)


def vstack(*systems: StateSpace) -> StateSpace:
    """``[y1; y2; ...] = [G1; G2; ...] u``: one shared input, outputs concatenated.

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same number of inputs and the same ``dt``.

    Returns
    -------
    StateSpace
        States stacked in argument order.

    Examples
    --------
    >>> vstack(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0], [2.0]]
    """
    g = block_diagonal(*systems)
    nu = systems[0].n_inputs
    if any(s.n_inputs != nu for s in systems):
        raise ValueError("vstack: every system must have the same number of inputs.")
    splitter = np.vstack([np.eye(nu)] * len(systems))
    return StateSpace(g.A, g.B @ splitter, g.C, g.D @ splitter, g.dt)


# --------------------------------------------------------------------------- frequency domain


def frequency_response(sys: StateSpace, freqs_hz, *, chunk: int = 512) -> np.ndarray:
    """FRF ``C (zI - A)^-1 B + D`` at ``z = exp(2j pi f dt)``, from the state space.

    Parameters
    ----------
    sys : StateSpace
        The system.
    freqs_hz : array_like, shape (K,)
        Frequencies in Hz.
    chunk : int, optional
        Frequencies solved per batch (bounds memory to ``chunk n^2`` complex numbers);
        default 512.

    Returns
    -------
    ndarray of complex, shape (K, ny, nu)
        In output units per input unit.

    Notes
    -----
    One batched linear solve ``(zI - A) X = B`` per frequency; no polynomials, so high
    orders stay accurate.  At a frequency exactly on a pole (``zI - A`` singular, e.g. DC
    of an integrator) the response is infinite and returned as ``inf``.

    Examples
    --------
    >>> g = tf_q_inverse([0.0, 1.0], [1.0], dt=1.0)   # one-sample delay
    >>> np.round(frequency_response(g, [0.25])[0, 0, 0], 12)
    np.complex128(-1j)
    """
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    z = np.exp(2j * np.pi * f * sys.dt)
    out = np.empty((f.size, sys.n_outputs, sys.n_inputs), dtype=complex)
    n = sys.n_states
    eye = np.eye(n)
    for start in range(0, f.size, chunk):
        zz = z[start:start + chunk]
        if n:
            out[start:start + chunk] = _resolvent_response(sys, zz, eye)
        else:
            out[start:start + chunk] = sys.D
    return out


def _resolvent_response(sys: StateSpace, zz: np.ndarray, eye: np.ndarray) -> np.ndarray:
    m = zz[:, None, None] * eye - sys.A
    rhs = np.broadcast_to(sys.B, (zz.size,) + sys.B.shape)
    try:
        return sys.C @ np.linalg.solve(m, rhs) + sys.D
    except np.linalg.LinAlgError:
        # A frequency sits exactly on a pole (e.g. DC of an integrator): solve one by one and
        # return an infinite response there instead of failing the whole batch.
        out = np.empty((zz.size, sys.n_outputs, sys.n_inputs), dtype=complex)
        for i in range(zz.size):
            try:
                out[i] = sys.C @ np.linalg.solve(m[i], sys.B) + sys.D
            except np.linalg.LinAlgError:
                out[i] = np.inf
        return out


def dc_gain(sys: StateSpace) -> np.ndarray:
    """Static gain ``C (I - A)^-1 B + D`` (``z = 1``).

    Parameters
    ----------
    sys : StateSpace
        System without a pole at ``z = 1``.

    Returns
    -------
    ndarray, shape (ny, nu)
        In output units per input unit.

    Examples
    --------
    >>> float(dc_gain(tf_q_inverse([1.0], [1.0, -0.5], dt=1.0))[0, 0])
    2.0
    """
    if sys.n_states == 0:
        return sys.D.copy()
    return sys.C @ np.linalg.solve(np.eye(sys.n_states) - sys.A, sys.B) + sys.D


# --------------------------------------------------------------------------- lifting


def lift_statespace(sys: StateSpace, factor: int) -> StateSpace:
    """Lifted system at period ``factor dt``.

    With ``u_bar(l) = [u(lF); u(lF+1); ...; u(lF+F-1)]`` (lifted channel
    ``phase n_inputs + channel``, as :mod:`lcmr_xr.kernels.lifting`), and likewise ``y_bar``:

    ``A^F``, ``[A^{F-1} B, ..., A B, B]``, ``[C; C A; ...; C A^{F-1}]`` and the block
    lower-triangular Toeplitz ``D_bar[i, j] = C A^{i-j-1} B`` (``i > j``), ``D`` on the diagonal.

    Parameters
    ----------
    sys : StateSpace
        Fast system.
    factor : int
        Lifting factor ``F >= 1``.

    Returns
    -------
    StateSpace
        ``n`` states, ``F nu`` inputs, ``F ny`` outputs, ``dt = F sys.dt``; the state is
        ``x(lF)``.

    Examples
    --------
    >>> g = lift_statespace(tf_q_inverse([0.0, 1.0], [1.0], dt=1.0), 2)
    >>> g.D.tolist()   # y(2l+1) = u(2l)
    [[0.0, 0.0], [1.0, 0.0]]
    """
    F = int(factor)
    if F < 1:
        raise ValueError(f"factor must be a positive integer, got {factor}.")
    n, nu, ny = sys.n_states, sys.n_inputs, sys.n_outputs
    powers = [np.eye(n)]
    for _ in range(F):
        powers.append(powers[-1] @ sys.A)
    obs = np.vstack([sys.C @ powers[i] for i in range(F)]) if n else np.zeros((F * ny, 0))
    ctrb = np.hstack([powers[F - 1 - j] @ sys.B for j in range(F)])
    # Markov parameters h[0] = D, h[k] = C A^{k-1} B
    markov = [sys.D] + [sys.C @ powers[k - 1] @ sys.B for k in range(1, F)]
    D = np.zeros((F * ny, F * nu))
    for i in range(F):
        for j in range(i + 1):
            D[i * ny:(i + 1) * ny, j * nu:(j + 1) * nu] = markov[i - j]
    return StateSpace(powers[F], ctrb, obs, D, F * sys.dt)


# --------------------------------------------------------------------------- stability


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


# --------------------------------------------------------------------------- simulation


def _default_block_length(sys: StateSpace) -> int:
    # Cost per sample: Toeplitz part ~ L nu ny, state part ~ n (nu + ny), plus a Python
    # step per block.  L ~ 2 n / sqrt(nu ny) balances the first two; clipped so tiny
    # systems still amortise the Python loop and big ones keep the Toeplitz matrix small.
    n = max(sys.n_states, 1)
    width = np.sqrt(max(sys.n_inputs * sys.n_outputs, 1))
    return int(np.clip(2 * n / width, 16, 256))


@functools.lru_cache(maxsize=16)
def _lifted_for_blocks(sys: StateSpace, block_length: int) -> StateSpace:
    """:func:`lift_statespace` memoised per system object (hashed by identity: systems are
    immutable), so Monte-Carlo runs on one loop pay for the block matrices once."""
    return lift_statespace(sys, block_length)


def simulate_lti(sys: StateSpace, u, x0=None, *, block_length: int | None = None) -> np.ndarray:
    """Response of a discrete LTI system to an input signal, without a per-sample Python loop.

    Parameters
    ----------
    sys : StateSpace
        The system (stable or not; growth is the caller's business).
    u : array_like, shape (..., N, nu)
        Input, time on axis -2; leading axes are independent experiments.
    x0 : array_like, shape (..., n), optional
        Initial state (broadcast over the leading axes of ``u``); default zero.
    block_length : int, optional
        Samples per block ``L``; default balances matmul and loop costs for ``sys``.

    Returns
    -------
    ndarray, shape (..., N, ny)
        Output, in output units.

    Notes
    -----
    With the ``L``-lifted system ``(A^L, Bbar, Obs, T)``: ``x_{b+1} = A^L x_b + Bbar u_b``
    over blocks ``b`` (a Python loop over ``N/L`` blocks, one small matmul each), then
    ``y_b = Obs x_b + T u_b`` for all blocks at once.  The input is zero-padded to a whole
    number of blocks; causality makes the padding harmless.

    Examples
    --------
    >>> g = tf_q_inverse([1.0], [1.0, -0.5], dt=1.0)
    >>> simulate_lti(g, np.ones((4, 1)))[:, 0].tolist()
    [1.0, 1.5, 1.75, 1.875]
    """
    u = np.asarray(u, dtype=float)
    if u.ndim < 2 or u.shape[-1] != sys.n_inputs:
        raise ValueError(
            f"u must have shape (..., N, {sys.n_inputs}) (time, then the {sys.n_inputs} inputs "
            f"of the system), got {u.shape}."
        )
    lead, N = u.shape[:-2], u.shape[-2]
    n, nu, ny = sys.n_states, sys.n_inputs, sys.n_outputs
    L = int(block_length) if block_length is not None else _default_block_length(sys)
    if L < 1:
        raise ValueError(f"block_length must be a positive integer, got {block_length}.")
    L = max(1, min(L, N))
    nb = -(-N // L)
    batch = int(np.prod(lead, dtype=int))
    ub = np.zeros((batch, nb * L, nu))
    ub[:, :N] = u.reshape(batch, N, nu)
    ub = ub.reshape(batch, nb, L * nu)  # lifted by L: channel = phase nu + input

    lifted = _lifted_for_blocks(sys, L)
    yb = ub @ lifted.D.T  # (batch, nb, L ny)
    x = np.zeros((batch, n)) if x0 is None else np.broadcast_to(
        np.asarray(x0, dtype=float), lead + (n,)).reshape(batch, n).copy()
    if n:
        drive = ub @ lifted.B.T  # (batch, nb, n): Bbar u_b for every block
        states = np.empty((batch, nb, n))
        a_t = lifted.A.T
        for b in range(nb):
            states[:, b] = x
            x = x @ a_t + drive[:, b]
        yb += states @ lifted.C.T
    return yb.reshape(batch, nb * L, ny)[:, :N].reshape(lead + (N, ny))


# --------------------------------------------------------------------------- multirate loop


@dataclass(frozen=True, eq=False)
class MultirateClosedLoop:
    """The multirate closed loop as one slow-rate LTI system (see :func:`multirate_closed_loop`).

    Parameters
    ----------
    system : StateSpace
        At the slow period ``Tl = F Th``.  Inputs, in this order: lifted ``r_h`` (``F nu``),
        lifted ``d_u`` (``F nu``), lifted ``d_y`` (``F ny``), ``reference`` (``ny``).
        Outputs: lifted ``u_h`` (``F nu``), ``y_l`` (``ny``), lifted ``y_h`` (``F ny``).
        States: ``[filter, plant]`` at ``x(lF)``, then the controller.
    factor : int
        ``F``.
    n_inputs, n_outputs : int
        ``nu`` and ``ny`` of the plant.
    spectral_radius : float
        Largest ``|eigenvalue|`` of ``system.A``.
    """

    system: StateSpace
    factor: int
    n_inputs: int
    n_outputs: int
    spectral_radius: float


class MultirateResponse(NamedTuple):
    """Signals of :func:`simulate_multirate`.

    Parameters
    ----------
    u : ndarray, shape (..., N, nu)
        Fast plant input as measured (before ``d_u`` is added).
    y_slow : ndarray, shape (..., M, ny)
        Slow measured output ``y_l(l) = y(lF)``.
    y : ndarray, shape (..., N, ny)
        Fast output (not measured; for stroke checks).
    """

    u: np.ndarray
    y_slow: np.ndarray
    y: np.ndarray


def _check_period(sys: StateSpace, name: str, expected: float, what: str):
    if not np.isclose(sys.dt, expected, rtol=_DT_RTOL, atol=0):
        raise ValueError(
            f"the {name} has sampling period {sys.dt} s but the loop needs {what} = {expected} s; "
            f"discretise the {name} at {expected} s."
        )


def multirate_closed_loop(plant: StateSpace, controller: StateSpace, filter: StateSpace | None,
                          factor: int, *, check_stability: bool = True) -> MultirateClosedLoop:
    """Build the multirate closed loop as ONE LTI system at the slow rate.

    Block diagram (fast period ``Th = plant.dt``, slow period ``Tl = F Th``)::

        e(l)   = reference(l) - y_l(l),        y_l(l) = y(lF)
        v(l)   = C e(l)                        slow controller
        v_h(n) = v(floor(n / F))               upsampler + zero-order hold
        u_h(n) = r_h(n) + (Fi v_h)(n)          fast filter; u_h is what is recorded
        y(n)   = P (u_h + d_u)(n) + d_y(n)     fast plant, input and output disturbances

    Parameters
    ----------
    plant : StateSpace
        ``P``, ``nu`` inputs, ``ny`` outputs, period ``Th``.
    controller : StateSpace
        ``C``, ``ny`` inputs (the error), ``nu`` outputs, period ``F Th``.
    filter : StateSpace or None
        ``Fi``, ``nu`` inputs and outputs, period ``Th``; ``None`` for the identity.
    factor : int
        ``F >= 1``.
    check_stability : bool, optional
        Refuse an unstable loop (default True).

    Returns
    -------
    MultirateClosedLoop
        The lifted closed loop; see its attributes for the input/output ordering.

    Raises
    ------
    ValueError
        On mismatched sizes or periods, an ill-posed algebraic loop
        (``I + D_P D_Fi D_C`` singular at phase 0) or an unstable loop.

    Notes
    -----
    The fast part ``[v_h, r_h, d_u, d_y] -> [u_h, y]`` (filter then plant) is lifted by
    ``F``; the hold makes ``v_h`` equal ``v(l)`` at every phase, so its lifted input matrix is
    the sum over phases.  A direct feedthrough from ``v`` to ``y(lF)`` (plant with ``D != 0``)
    closes an algebraic loop at the slow rate, solved exactly:
    ``(I + D_yv D_C) y_l = ...``.

    Examples
    --------
    >>> P = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    >>> C = static_gain(0.2, dt=1.0)
    >>> loop = multirate_closed_loop(P, C, None, 2)
    >>> loop.system.n_inputs, loop.system.n_outputs   # [r(2), d_u(2), d_y(2), ref(1)], [u(2), y_l, y(2)]
    (7, 5)
    """
    F = int(factor)
    if F < 1:
        raise ValueError(f"factor must be a positive integer, got {factor}.")
    nu, ny = plant.n_inputs, plant.n_outputs
    th = plant.dt
    if filter is None:
        filter = static_gain(np.eye(nu), th)
    if (controller.n_inputs, controller.n_outputs) != (ny, nu):
        raise ValueError(
            f"the controller maps the error ({ny} plant outputs) to the {nu} plant inputs, so it "
            f"needs {ny} inputs and {nu} outputs; got {controller.n_inputs} inputs and "
            f"{controller.n_outputs} outputs."
        )
    if (filter.n_inputs, filter.n_outputs) != (nu, nu):
        raise ValueError(
            f"the filter sits between the controller and the {nu} plant inputs, so it needs {nu} "
            f"inputs and outputs; got {filter.n_inputs} and {filter.n_outputs}."
        )
    _check_period(filter, "filter", th, "the plant period Th")
    _check_period(controller, "controller", F * th, f"F Th (F={F})")

    # Fast part G: inputs [v_h, r, d_u, d_y], outputs [u_h, y], states [x_filter, x_plant].
    Af, Bf, Cf, Df = filter.A, filter.B, filter.C, filter.D
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    nf, npl = filter.n_states, plant.n_states
    z = np.zeros
    A_g = np.block([[Af, z((nf, npl))], [Bp @ Cf, Ap]])
    B_g = np.block([[Bf, z((nf, nu)), z((nf, nu)), z((nf, ny))],
                    [Bp @ Df, Bp, Bp, z((npl, ny))]])
    C_g = np.block([[Cf, z((nu, npl))], [Dp @ Cf, Cp]])
    D_g = np.block([[Df, np.eye(nu), z((nu, nu)), z((nu, ny))],
                    [Dp @ Df, Dp, Dp, np.eye(ny)]])
    g = lift_statespace(StateSpace(A_g, B_g, C_g, D_g, th), F)

    n_in, n_out = 2 * nu + nu + ny, nu + ny
    phase = np.arange(F)[:, None]
    cols_v = (phase * n_in + np.arange(nu)).ravel()
    cols_w = np.concatenate([(phase * n_in + off + np.arange(width)).ravel()
                             for off, width in ((nu, nu), (2 * nu, nu), (3 * nu, ny))])
    rows_u = (phase * n_out + np.arange(nu)).ravel()
    rows_y = (phase * n_out + nu + np.arange(ny)).ravel()
    rows_z = np.concatenate([rows_u, rows_y[:ny], rows_y])  # [u_bar, y_l, y_bar]
    # The hold repeats v(l) at every phase: sum the lifted columns over phases.
    B_v = g.B[:, cols_v].reshape(-1, F, nu).sum(axis=1)
    D_v = g.D[:, cols_v].reshape(-1, F, nu).sum(axis=1)
    B_w, D_w = g.B[:, cols_w], g.D[:, cols_w]
    nw = cols_w.size

    Ac, Bc, Cc, Dc = controller.A, controller.B, controller.C, controller.D
    ng, nc = g.n_states, controller.n_states
    # Everything below is a linear map of s = [x_g, x_c, w, ref].
    ns = ng + nc + nw + ny
    sel_xg, sel_xc = slice(0, ng), slice(ng, ng + nc)
    sel_w, sel_ref = slice(ng + nc, ng + nc + nw), slice(ng + nc + nw, ns)

    def embed(**parts):
        m = np.zeros((next(iter(parts.values())).shape[0], ns))
        for key, val in parts.items():
            m[:, {"xg": sel_xg, "xc": sel_xc, "w": sel_w, "ref": sel_ref}[key]] = val
        return m

    y0 = slice(nu, nu + ny)  # y at phase 0 = rows nu..nu+ny of the lifted output
    C_y, D_yv, D_yw = g.C[y0], D_v[y0], D_w[y0]
    loop_matrix = np.eye(ny) + D_yv @ Dc
    if np.linalg.cond(loop_matrix) > 1e12:
        raise ValueError(
            "the multirate loop has an ill-posed algebraic loop: I + D_P D_Fi D_C (direct "
            "feedthrough from controller output to y(lF)) is singular. Add a delay to the "
            "controller or the plant, or change the feedthrough gains."
        )
    y_l = np.linalg.solve(loop_matrix, embed(xg=C_y, xc=D_yv @ Cc, w=D_yw, ref=D_yv @ Dc))
    v = embed(xc=Cc, ref=Dc) - Dc @ y_l
    x_g_next = embed(xg=g.A, w=B_w) + B_v @ v
    x_c_next = embed(xc=Ac, ref=Bc) - Bc @ y_l
    out = (embed(xg=g.C, w=D_w) + D_v @ v)[rows_z]
    out[F * nu:F * nu + ny] = y_l  # identical to the phase-0 rows; keep the solved form
    state_rows = np.vstack([x_g_next, x_c_next])
    nx = ng + nc
    system = StateSpace(state_rows[:, :nx], state_rows[:, nx:], out[:, :nx], out[:, nx:], F * th)
    if check_stability:
        rho = check_stable(
            system, f"multirate closed loop (plant, controller, filter, F={F})",
            "Check the controller sign (e = reference - y_l, negative feedback), the loop "
            "gains, the filter, and that controller and plant are sampled at F Th and Th.")
    else:
        rho = spectral_radius(system.A)
    return MultirateClosedLoop(system, F, nu, ny, rho)


def _signal(x, shape_tail: tuple, name: str, lead: tuple) -> np.ndarray:
    if x is None:
        return np.zeros(lead + shape_tail)
    a = np.asarray(x, dtype=float)
    if a.shape[-2:] != shape_tail:
        raise ValueError(f"{name} must have shape (..., {shape_tail[0]}, {shape_tail[1]}), "
                         f"got {a.shape}.")
    return np.broadcast_to(a, lead + shape_tail)


def simulate_multirate(loop: MultirateClosedLoop, r, d_u=None, d_y=None, reference=None,
                       *, block_length: int | None = None) -> MultirateResponse:
    """Simulate the multirate closed loop from rest, all at once at the slow rate.

    Parameters
    ----------
    loop : MultirateClosedLoop
        From :func:`multirate_closed_loop`.
    r : array_like, shape (..., N, nu)
        Fast excitation ``r_h`` added at the plant input; ``N`` a multiple of ``F``.
    d_u : array_like, shape (..., N, nu), optional
        Fast input disturbance, added after ``u_h`` is measured; default zero.
    d_y : array_like, shape (..., N, ny), optional
        Fast output disturbance; default zero.
    reference : array_like, shape (..., N/F, ny), optional
        Slow reference (e.g. run-out), enters as ``e = reference - y_l``; default zero.
    block_length : int, optional
        Passed to :func:`simulate_lti` (slow samples per block).

    Returns
    -------
    MultirateResponse
        ``u`` (..., N, nu), ``y_slow`` (..., N/F, ny), ``y`` (..., N, ny).

    Examples
    --------
    >>> P = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    >>> loop = multirate_closed_loop(P, static_gain(0.2, dt=1.0), None, 2)
    >>> out = simulate_multirate(loop, np.ones((8, 1)))
    >>> out.u.shape, out.y_slow.shape, out.y.shape
    ((8, 1), (4, 1), (8, 1))
    """
    F, nu, ny = loop.factor, loop.n_inputs, loop.n_outputs
    r = np.asarray(r, dtype=float)
    if r.ndim < 2 or r.shape[-1] != nu:
        raise ValueError(f"r must have shape (..., N, {nu}) (time, plant inputs), got {r.shape}.")
    N = r.shape[-2]
    if N % F:
        raise ValueError(
            f"{N} fast samples cannot be lifted by factor {F}; trim r to {N - N % F} samples.")
    M = N // F
    lead = np.broadcast_shapes(*[np.shape(x)[:-2] for x in (r, d_u, d_y, reference)
                                 if x is not None])
    parts = [_signal(r, (N, nu), "r", lead), _signal(d_u, (N, nu), "d_u", lead),
             _signal(d_y, (N, ny), "d_y", lead)]
    # (N, c) -> (M, F c) is exactly the phase-major lifting of the kernels.
    lifted = [p.reshape(lead + (M, F * p.shape[-1])) for p in parts]
    lifted.append(_signal(reference, (M, ny), "reference", lead))
    out = simulate_lti(loop.system, np.concatenate(lifted, axis=-1), block_length=block_length)
    u = out[..., :F * nu].reshape(lead + (N, nu))
    y_slow = out[..., F * nu:F * nu + ny]
    y = out[..., F * nu + ny:].reshape(lead + (N, ny))
    return MultirateResponse(u, y_slow, y)
