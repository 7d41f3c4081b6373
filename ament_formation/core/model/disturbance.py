"""Bounded smooth disturbance g(t) of the dynamics (19)-(20) (spec S2.2, S2.3, S3.3).

g_k(t) = sum_m A_km sin(2 pi f_km t + phi_km) per robot, with A_km >= 0 and sum_m A_km = g_bar_k,
so |g1| <= g1_bar [m/s^2] and |g2| <= g2_bar [rad/s^2] hold exactly, g is C-infinity and the
derivatives are bounded. Frequencies and phases are drawn from ``numpy.random.default_rng(seed)``:
the same seed gives the same disturbance. The closed loop evaluates it per robot with the kernels
:func:`disturbance_k` (direct) and :func:`disturbance_phasor_advance_k` (phasor rotation); the
twin and :meth:`Disturbance.__call__` through :func:`disturbance_grid_k`, which calls
:func:`disturbance_k`.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from ament_formation.core.errors import ConfigError


@dataclass(frozen=True)
class Disturbance:
    """Sum-of-sinusoids disturbance for N robots, M terms per component.

    ``amplitude`` (N, 2, M) [m/s^2 | rad/s^2], ``freq_hz`` (N, 2, M), ``phase_rad`` (N, 2, M).
    Calling it with a time ``t_s`` returns g (N, 2) rows [g1_mps2, g2_radps2].
    """

    amplitude: np.ndarray
    freq_hz: np.ndarray
    phase_rad: np.ndarray

    def __post_init__(self) -> None:
        shape = None
        for name in ('amplitude', 'freq_hz', 'phase_rad'):
            value = np.ascontiguousarray(np.asarray(getattr(self, name), dtype=float))
            if value.ndim != 3 or value.shape[1] != 2:
                raise ConfigError(f'must have shape (N, 2, M) (got {value.shape})', name)
            if shape is not None and value.shape != shape:
                raise ConfigError(
                    f'must have the shape of amplitude {shape} (got {value.shape})', name
                )
            if not np.all(np.isfinite(value)):
                raise ConfigError('must be finite', name)
            shape = value.shape
            object.__setattr__(self, name, value)
        if np.any(self.amplitude < 0):
            raise ConfigError('must be >= 0', 'amplitude')

    @property
    def n(self) -> int:
        return int(self.amplitude.shape[0])

    @property
    def bound(self) -> np.ndarray:
        """(N, 2) sup |g_k| = sum_m A_km."""
        return self.amplitude.sum(axis=2)

    @classmethod
    def from_bounds(
        cls,
        n_robots: int,
        bound,
        seed: int,
        n_terms: int = 4,
        f_min_hz: float = 0.05,
        f_max_hz: float = 1.0,
    ) -> 'Disturbance':
        """Deterministic disturbance with |g_k| <= bound[k] for ``n_robots`` robots.

        ``bound`` (2,) [g1_bar_mps2, g2_bar_radps2] (or (N, 2)); ``seed`` int; ``n_terms`` M >= 1;
        frequencies uniform in [f_min_hz, f_max_hz], phases uniform, weights Dirichlet(1).
        """
        if int(n_robots) != n_robots or n_robots < 0:
            raise ConfigError(f'must be an integer >= 0 (got {n_robots!r})', 'n_robots')
        if int(n_terms) != n_terms or n_terms < 1:
            raise ConfigError(f'must be an integer >= 1 (got {n_terms!r})', 'n_terms')
        bound = np.broadcast_to(np.asarray(bound, dtype=float), (int(n_robots), 2))
        if not (np.all(np.isfinite(bound)) and np.all(bound >= 0)):
            raise ConfigError(
                f'must be finite and >= 0 (got {np.asarray(bound).tolist()!r})', 'bound'
            )
        if not (0 < f_min_hz <= f_max_hz and math.isfinite(f_max_hz)):
            raise ConfigError(
                f'need 0 < f_min_hz <= f_max_hz (got {f_min_hz}, {f_max_hz})', 'f_min_hz'
            )
        rng = np.random.default_rng(seed)
        shape = (int(n_robots), 2, int(n_terms))
        weights = rng.dirichlet(np.ones(int(n_terms)), size=(int(n_robots), 2))
        freq = rng.uniform(f_min_hz, f_max_hz, size=shape)
        phase = rng.uniform(0.0, 2.0 * math.pi, size=shape)
        return cls(weights * bound[:, :, None], freq, phase)

    @classmethod
    def zero(cls, n_robots: int) -> 'Disturbance':
        """G == 0 for ``n_robots`` robots."""
        z = np.zeros((int(n_robots), 2, 1))
        return cls(z, z + 1.0, z)

    def __call__(self, t_s: float) -> np.ndarray:
        """g(t_s) (N, 2)."""
        return self.at_times(np.array([float(t_s)]))[0]

    def at_times(self, t_s: np.ndarray) -> np.ndarray:
        """The disturbance at every time of ``t_s`` (T,): (T, N, 2), by :func:`disturbance_k`."""
        t = np.ascontiguousarray(np.asarray(t_s, dtype=float).reshape(-1))
        out = np.empty((t.shape[0], self.n, 2))
        disturbance_grid_k(t, self.amplitude, self.freq_hz, self.phase_rad, out)
        return out

    def step_rotation(self, h_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(cos, sin) of the phase advance 2 pi f h_s of every term, each (N, 2, M), for
        :func:`disturbance_phasor_advance_k`.
        """
        ang = 2.0 * math.pi * self.freq_hz * h_s
        return np.cos(ang), np.sin(ang)

    def take(self, index) -> 'Disturbance':
        """The disturbance of the robots selected by ``index``."""
        m = self.amplitude.shape[2]
        return Disturbance(
            self.amplitude[index].reshape(-1, 2, m),
            self.freq_hz[index].reshape(-1, 2, m),
            self.phase_rad[index].reshape(-1, 2, m),
        )


# implements: S2.3
@njit(cache=True, error_model='numpy')
def disturbance_k(t, amp, freq, phase):
    """g(t) = sum_m A sin(2 pi f t + phi) for one robot; amp/freq/phase (2, M) -> (g1, g2)."""
    g1 = 0.0
    g2 = 0.0
    for m in range(amp.shape[1]):
        g1 += amp[0, m] * math.sin(2.0 * math.pi * freq[0, m] * t + phase[0, m])
        g2 += amp[1, m] * math.sin(2.0 * math.pi * freq[1, m] * t + phase[1, m])
    return g1, g2


@njit(cache=True, error_model='numpy')
def disturbance_grid_k(t, amp, freq, phase, out):
    """The disturbance of every robot at every time: t (T,), amp/freq/phase (N, 2, M) -> out
    (T, N, 2).
    """
    for s in range(t.shape[0]):
        for i in range(amp.shape[0]):
            g1, g2 = disturbance_k(t[s], amp[i], freq[i], phase[i])
            out[s, i, 0] = g1
            out[s, i, 1] = g2


@njit(cache=True, error_model='numpy')
def disturbance_phasor_init_k(t, freq, phase, sin_out, cos_out):
    """Start the phasors of one robot at time t:
    sin_out/cos_out (2, M) = sin/cos(2 pi f t + phi).
    """
    for k in range(2):
        for m in range(freq.shape[1]):
            arg = 2.0 * math.pi * freq[k, m] * t + phase[k, m]
            sin_out[k, m] = math.sin(arg)
            cos_out[k, m] = math.cos(arg)


@njit(cache=True, error_model='numpy', forceinline=True)
def disturbance_phasor_advance_k(amp, sin_st, cos_st, cos_step, sin_step):
    """Rotate the phasors of one robot by one step (angles 2 pi f h, from
    :meth:`Disturbance.step_rotation`) in place and return g (g1, g2) at the new time.

    No transcendental call per step: a closed loop with fixed dt evaluates g at t + dt/2 and t + dt
    by two half-step rotations (reusing g(t) of the previous step). Rounding drift is ~1e-16 per
    step relative to the bound; re-initialise with :func:`disturbance_phasor_init_k` now and then.
    """
    g1 = 0.0
    g2 = 0.0
    for m in range(amp.shape[1]):
        s0 = sin_st[0, m]
        c0 = cos_st[0, m]
        sn = s0 * cos_step[0, m] + c0 * sin_step[0, m]
        cn = c0 * cos_step[0, m] - s0 * sin_step[0, m]
        sin_st[0, m] = sn
        cos_st[0, m] = cn
        g1 += amp[0, m] * sn
        s0 = sin_st[1, m]
        c0 = cos_st[1, m]
        sn = s0 * cos_step[1, m] + c0 * sin_step[1, m]
        cn = c0 * cos_step[1, m] - s0 * sin_step[1, m]
        sin_st[1, m] = sn
        cos_st[1, m] = cn
        g2 += amp[1, m] * sn
    return g1, g2
