"""The controlled stop (DESIGN §7): what a robot's controller commands when its inputs go stale
(no camera pose for ``pose_timeout_s``, its parent's state lost): wheels to rest, held there.
"""

from __future__ import annotations

import numpy as np

from ament_formation.core.model.dynamics import b2_inv, f2, PlantCoeffs
from ament_formation.core.params import ControlGains


def stop_torque(
    state: np.ndarray, k: PlantCoeffs, stop_time_s: float, gains: ControlGains
) -> np.ndarray:
    """Controlled stop (DESIGN §7): torques (N, 2) that bring (v, omega) to rest and hold them
    there against the bounded disturbance g.

    A sliding-mode velocity regulator on sigma = x2 (S2.2: x2dot = f2 + B2 u + g):
    u = B2^-1 (-x2 / T - K sat(x2 / eps) - f2), with T = ``stop_time_s``, the point gain
    K = (K_p, K_p / d) and eps = (eps_p, eps_p / d) / 2 from the formation law (S3.3, S3.5), so the
    residual speed is |g| / (1/T + K/eps): about 1 mm/s and 0.01 rad/s with the defaults, where a
    plain -x2/T brake would creep at g T. Uniformly scaled into the torque limit (S3.6).
    """
    x2 = state[:, 3:5]
    gain = gains.switching_gain_mps2 * np.stack((np.ones_like(k.d), 1.0 / k.d), axis=-1)
    eps = 0.5 * gains.boundary_layer_mps * np.stack((np.ones_like(k.d), 1.0 / k.d), axis=-1)
    x2dot = -x2 / stop_time_s - gain * np.clip(x2 / eps, -1.0, 1.0) - f2(state, k)
    u = np.einsum('nij,nj->ni', b2_inv(k), x2dot)
    scale = np.maximum(1.0, np.max(np.abs(u), axis=1) / k.tau_max)
    return u / scale[:, None]
