"""The one Kalman filter of aerotrack: constant velocity in world coordinates (Yu & Medioni 6-8).

State ``x = [l_x, l_y, w, h, v_x, v_y]`` (centre position, size and velocity, world units and world
units per second); observation ``z = [l_x, l_y, w, h]`` (world units). Position follows a
constant-velocity model driven by white-noise acceleration, the size a random walk:

* transition (eq. 6): ``x_{t+dt} = A(dt) x_t + w``, ``w ~ N(0, Q(dt))``
* observation (eq. 7): ``z = H x + v``, ``v ~ N(0, R(z))``
* motion likelihood (eq. 8): ``N(e; 0, S)`` with innovation ``e = z - H A x`` and
  ``S = H (A P A^T + Q) H^T + R``.

The filter is a set of pure functions on plain arrays (``transition``, ``process_noise``,
``measurement_noise``, ``initiate``, ``predict``, ``update``), compiled by numba so that the MCMC
hot loop can call them without Python overhead (they are called from Python as usual), and
:class:`ConstantVelocityKF`, a small class holding the noise parameters. Every stage
(local association, bridging, prediction) uses this filter with its own parameters; never copy it.

Time steps are in seconds (``dt`` may be any positive number: a gap of several frames is one
step), so the parameters mean the same at any frame rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

try:  # numba is a core dependency; the fallback keeps the module importable while it installs
    from numba import njit as _njit
except ImportError:  # pragma: no cover
    def _njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

DIM_X = 6
DIM_Z = 4


@_njit(cache=True)
def transition(dt: float) -> np.ndarray:
    """(6, 6) constant-velocity transition ``A(dt)`` (eq. 6) for a step of ``dt`` seconds."""
    A = np.eye(DIM_X)
    A[0, 4] = dt
    A[1, 5] = dt
    return A


@_njit(cache=True)
def process_noise(dt: float, accel_std: float, size_std: float) -> np.ndarray:
    """(6, 6) process noise ``Q(dt)``.

    Parameters
    ----------
    dt : float
        Step in seconds.
    accel_std : float
        Standard deviation of the white-noise acceleration, world units / s^2 (each axis).
    size_std : float
        Random-walk standard deviation of width and height after one second, world units.
    """
    q = accel_std * accel_std
    Q = np.zeros((DIM_X, DIM_X))
    for i in range(2):
        Q[i, i] = 0.25 * dt**4 * q
        Q[i, i + 4] = 0.5 * dt**3 * q
        Q[i + 4, i] = 0.5 * dt**3 * q
        Q[i + 4, i + 4] = dt**2 * q
    Q[2, 2] = size_std * size_std * dt
    Q[3, 3] = size_std * size_std * dt
    return Q


@_njit(cache=True)
def measurement_noise(size: np.ndarray, pos_std: float, pos_frac: float, size_std: float,
                      size_frac: float) -> np.ndarray:
    """(4, 4) diagonal measurement noise ``R`` for an observation of box size ``size`` (2,).

    Position noise per axis is ``hypot(pos_std, pos_frac * size)`` and size noise
    ``hypot(size_std, size_frac * size)``: detections of big blobs are less precise in world units.
    """
    R = np.zeros((DIM_Z, DIM_Z))
    for i in range(2):
        s = abs(size[i])
        R[i, i] = pos_std * pos_std + (pos_frac * s) ** 2
        R[i + 2, i + 2] = size_std * size_std + (size_frac * s) ** 2
    return R


@_njit(cache=True)
def initiate(z: np.ndarray, R: np.ndarray, vel_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State (6,) and covariance (6, 6) from one observation ``z`` (4,), velocity unknown.

    ``vel_std`` (world units / s) is the prior spread of the velocity: about half the maximum speed.
    """
    x = np.zeros(DIM_X)
    x[:4] = z[:4]
    P = np.zeros((DIM_X, DIM_X))
    P[:4, :4] = R
    P[4, 4] = vel_std * vel_std
    P[5, 5] = vel_std * vel_std
    return x, P


@_njit(cache=True)
def predict(x: np.ndarray, P: np.ndarray, A: np.ndarray, Q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Prior state (6,) and covariance (6, 6) after one transition (eq. 6): ``A x``,
    ``A P A^T + Q``.

    Written as explicit loops so that the compiled twin allocates nothing but its results.
    """
    n = x.shape[0]
    xp = np.zeros(n)
    AP = np.zeros((n, n))
    Pp = np.zeros((n, n))
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += A[i, k] * x[k]
        xp[i] = acc
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += A[i, k] * P[k, j]
            AP[i, j] = acc
    for i in range(n):
        for j in range(n):
            acc = Q[i, j]
            for k in range(n):
                acc += AP[i, k] * A[j, k]
            Pp[i, j] = acc
    return xp, Pp


@_njit(cache=True)
def cholesky(S: np.ndarray) -> tuple[np.ndarray, float]:
    """Lower Cholesky factor L (m, m) of a symmetric positive-definite S (m, m) and ``log det S``.

    logdet is +inf (and L incomplete) when S is not positive definite.
    """
    m = S.shape[0]
    L = np.zeros((m, m))
    logdet = 0.0
    for i in range(m):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if acc <= 0.0:
                    return L, np.inf
                L[i, i] = np.sqrt(acc)
                logdet += np.log(acc)
            else:
                L[i, j] = acc / L[j, j]
    return L, logdet


@_njit(cache=True)
def mahalanobis(S: np.ndarray, e: np.ndarray) -> tuple[float, float]:
    """Squared Mahalanobis distance ``e^T S^-1 e`` of ``e`` (m,) and ``log det S`` (one Cholesky
    factorisation and a forward substitution); (+inf, +inf) when S is not positive definite."""
    L, logdet = cholesky(S)
    if not np.isfinite(logdet):
        return np.inf, np.inf
    m = S.shape[0]
    y = np.zeros(m)
    d2 = 0.0
    for i in range(m):
        acc = e[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
        d2 += y[i] * y[i]
    return d2, logdet


@_njit(cache=True)
def cholesky_solve(S: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, float]:
    """Solve ``S X = B`` for symmetric positive-definite S (m, m), B (m, k); also ``log det S``.

    Returns (X, logdet); X is all-NaN and logdet +inf when S is not positive definite.
    """
    L, logdet = cholesky(S)
    if not np.isfinite(logdet):
        return np.full(B.shape, np.nan), np.inf
    m = S.shape[0]
    nb = B.shape[1]
    X = np.zeros((m, nb))
    for c in range(nb):
        y = np.zeros(m)
        for i in range(m):
            acc = B[i, c]
            for k in range(i):
                acc -= L[i, k] * y[k]
            y[i] = acc / L[i, i]
        for i in range(m - 1, -1, -1):
            acc = y[i]
            for k in range(i + 1, m):
                acc -= L[k, i] * X[k, c]
            X[i, c] = acc / L[i, i]
    return X, logdet


@_njit(cache=True)
def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Posterior after observing ``z`` (4,) with noise ``R`` (4, 4), and the motion likelihood.

    Returns
    -------
    x, P : ndarray (6,), (6, 6)
        Posterior state and covariance.
    loglik : float
        ``log N(e; 0, S)`` (eq. 8 in log space), ``e = z - H x``, ``S = H P H^T + R``.
    d2 : float
        Squared Mahalanobis distance ``e^T S^-1 e`` (chi-square with 4 degrees of freedom).
    """
    n = x.shape[0]
    m = 4
    S = np.zeros((m, m))
    for i in range(m):
        for j in range(m):
            S[i, j] = P[i, j] + R[i, j]
    # [S^-1 e | S^-1 H P] in one solve
    B = np.zeros((m, n + 1))
    for i in range(m):
        B[i, 0] = z[i] - x[i]
        for j in range(n):
            B[i, j + 1] = P[i, j]
    X, logdet = cholesky_solve(S, B)
    d2 = 0.0
    for i in range(m):
        d2 += B[i, 0] * X[i, 0]
    loglik = -0.5 * d2 - 0.5 * logdet - 0.5 * m * np.log(2.0 * np.pi)
    xn = np.zeros(n)
    Pn = np.zeros((n, n))
    for i in range(n):
        acc = x[i]
        for k in range(m):
            acc += P[i, k] * X[k, 0]  # K e with K = P H^T S^-1
        xn[i] = acc
        for j in range(n):
            acc = P[i, j]
            for k in range(m):
                acc -= P[i, k] * X[k, j + 1]  # K H P
            Pn[i, j] = acc
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (Pn[i, j] + Pn[j, i])
            Pn[i, j] = v
            Pn[j, i] = v
    return xn, Pn, loglik, d2


# The pure functions above are compiled by numba (callable from Python as usual); these aliases
# name them where compiled code calls them.
transition_nb = transition
process_noise_nb = process_noise
measurement_noise_nb = measurement_noise
initiate_nb = initiate
predict_nb = predict
update_nb = update
mahalanobis_nb = mahalanobis


@dataclass(frozen=True)
class ConstantVelocityKF:
    """Noise parameters of the constant-velocity filter, in world units and seconds.

    Attributes
    ----------
    accel_std : float
        White-noise acceleration, world units / s^2. Raising it follows manoeuvres (and, in image
        coordinates, camera shake) but widens the gate and lets neighbours be confused.
    size_std : float
        Size random walk after 1 s, world units.
    pos_std, pos_frac : float
        Observation position noise: absolute (world units) and as a fraction of the box size.
    size_std_obs, size_frac : float
        Observation size noise: absolute and as a fraction of the size.
    vel_std : float
        Velocity spread of a new track, world units / s.
    """

    accel_std: float = 3.0
    size_std: float = 0.5
    pos_std: float = 0.3
    pos_frac: float = 0.05
    size_std_obs: float = 0.3
    size_frac: float = 0.08
    vel_std: float = 10.0

    def as_array(self) -> np.ndarray:
        """The 7 parameters as a float64 array, in field order (for compiled kernels)."""
        return np.array([self.accel_std, self.size_std, self.pos_std, self.pos_frac,
                         self.size_std_obs, self.size_frac, self.vel_std], dtype=np.float64)

    def R(self, z: np.ndarray) -> np.ndarray:
        return measurement_noise(np.asarray(z, float)[2:4], self.pos_std, self.pos_frac,
                                 self.size_std_obs, self.size_frac)

    def initiate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance from a first observation ``z`` = (x, y, w, h), world units."""
        z = np.asarray(z, dtype=np.float64)
        return initiate(z, self.R(z), self.vel_std)

    def predict(self, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Prior ``dt`` seconds later (dt < 0 runs the model backwards)."""
        return predict(x, P, transition(dt), process_noise(abs(dt), self.accel_std, self.size_std))

    def update(self, x: np.ndarray, P: np.ndarray, z: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Posterior, log-likelihood (eq. 8) and Mahalanobis distance of observation ``z``."""
        z = np.asarray(z, dtype=np.float64)
        return update(x, P, z, self.R(z))

    def filter(self, zs: np.ndarray, times: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Filter a sequence of observations ``zs`` (N, 4) at ``times`` (N,) seconds.

        Returns the posterior states (N, 6), covariances (N, 6, 6) and the per-step log-likelihoods
        (N,) (the first is 0: it initiates the track).
        """
        zs = np.asarray(zs, dtype=np.float64).reshape(-1, 4)
        times = np.asarray(times, dtype=np.float64)
        xs, Ps, ll, _ = filter_sequence(zs, times, self.as_array())
        return xs, Ps, ll


@_njit(cache=True)
def filter_sequence(zs, times, params):
    """Compiled filter over observations ``zs`` (N, 4) at ``times`` (N,) seconds, initiated at
    zs[0].

    ``params`` is :meth:`ConstantVelocityKF.as_array`. Returns states (N, 6), covariances (N, 6, 6),
    log-likelihoods (N,) and squared Mahalanobis distances (N,) of each step (0 for the first).
    """
    n = zs.shape[0]
    xs = np.zeros((n, DIM_X))
    Ps = np.zeros((n, DIM_X, DIM_X))
    ll = np.zeros(n)
    d2 = np.zeros(n)
    if n == 0:
        return xs, Ps, ll, d2
    x, P = initiate_nb(zs[0], measurement_noise_nb(zs[0, 2:4], params[2], params[3], params[4],
                                                   params[5]), params[6])
    xs[0] = x
    Ps[0] = P
    for i in range(1, n):
        dt = abs(times[i] - times[i - 1])
        x, P = predict_nb(x, P, transition_nb(times[i] - times[i - 1]),
                          process_noise_nb(dt, params[0], params[1]))
        R = measurement_noise_nb(zs[i, 2:4], params[2], params[3], params[4], params[5])
        x, P, ll[i], d2[i] = update_nb(x, P, zs[i], R)
        xs[i] = x
        Ps[i] = P
    return xs, Ps, ll, d2
