"""The camera-offset calibration of the snake pipe-tracking paper (Section 2.4.1, Fig. 5), fitted for this snake.

The head camera swings sideways with the slithering gait; Alg. 3 adds the
camera's lateral offset from the robot's central line to the pipe's offset
in the camera. The paper reconstructs it from the head joint alone, Eqs. (4)-(6)
(`spikejax.vision.pipe.camera_offset`, their one home):

    theta = a sin(omega t + phi)                                    (4)
    theta_tuned = alpha (theta cos(phi_pos) + theta'/omega sin(phi_pos))   (5)
    Position = A sin(theta_tuned)                                   (6)

with the head joint's angle and velocity smoothed by "a mean filter on the
timeline", and the tuple ``(A, alpha, phi_pos)`` fitted by FFT to the
camera's measured swing. The paper's tuples (V-REP, NRP) belong to other
robots; `calibrate` fits ours from a straight run of the physics with the
default gait:

1. `straight_run`: the head joint's encoder (angle, velocity), the camera's
   position and the centre of mass at every 20 ms control step.
2. `true_offset`: the camera's signed lateral offset from the central line,
   positive to the right of the direction of motion. The central line is the
   camera's path averaged over one gait period (a centred moving mean), its
   direction that of the averaged path: the camera's swing about its mean
   path. (Measured from the centre of mass's averaged path instead, the
   camera's mean offset also wanders by about +-2 cm from period to period,
   which the head joint cannot predict; `true_offset` gives both.)
3. `fit`: after the first period (the start-up transient), ``omega`` is the
   gait's and ``a`` the amplitude of the head joint's fundamental (the FFT
   coefficient at ``omega``, a least-squares sine over whole periods);
   ``alpha = (pi / 2) / a`` as the paper defines it ("the ratio of the 90
   degrees to a"; ``A`` and ``alpha`` are otherwise degenerate for a sine-like
   swing); then ``(A, phi_pos)`` by least squares on the mean-filtered
   encoder signals: ``A`` in closed form for each ``phi_pos`` on a 0.5 degree
   grid, the best pair refined by a golden-section search. The filter's delay
   is absorbed in ``phi_pos``.

Our figures (`fit` of a 4-period run, tested over 10 more periods in
``tests/test_calibration.py``) are in `SWING` and docs/EQUATIONS.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake.gait import GaitParams, gait_params, gait_period, joint_targets
from spikejax.errors import UserError
from spikejax.vision import pipe as pp

__all__ = [
    "SWING",
    "WINDOW",
    "Run",
    "SwingFit",
    "calibrate",
    "estimate",
    "fit",
    "straight_run",
    "true_offset",
]

WINDOW = 5  # control steps (0.1 s) of the mean filter; the paper gives none


class SwingFit(NamedTuple):
    """The fitted Eq. (4)-(6) tuple, with what it was fitted on.

    Attributes:
        swing_amplitude: ``A``, m, > 0 (``(-A, phi_pos + pi)`` is the same swing).
        swing_ratio: ``alpha = (pi/2) / a``.
        swing_phase: ``phi_pos``, rad.
        omega: the gait's angular frequency, rad/s.
        joint_amplitude: ``a``, the head joint's amplitude, rad.
        window: the mean filter's window, control steps.
        rmse: the fit's RMS residual on its run, m.
    """

    swing_amplitude: float
    swing_ratio: float
    swing_phase: float
    omega: float
    joint_amplitude: float
    window: int
    rmse: float

    def track_params(self, **kw) -> pp.TrackParams:
        """`spikejax.vision.pipe.track_params` with this swing (``kw``: the other arguments)."""
        return pp.track_params(
            swing_amplitude=self.swing_amplitude,
            swing_ratio=self.swing_ratio,
            swing_phase=self.swing_phase,
            omega=self.omega,
            **kw,
        )


# Fitted by `calibrate()` (4 periods, the default gait, tuned MuJoCo settings, window 5); see the module's notes.
# Runs starting 0, 0.7, 1.3 and 2 s into the gait (4-6 periods) agree to 0.2 % in A and 0.4 degrees in phi_pos.
SWING = SwingFit(
    swing_amplitude=0.0768,
    swing_ratio=2.267,
    swing_phase=2.104,
    omega=2 * math.pi / 2.5,
    joint_amplitude=0.693,
    window=WINDOW,
    rmse=0.0141,
)


class Run(NamedTuple):
    """A straight run, one row per control step (host arrays).

    Attributes:
        t: ``(n,)`` s, each step's end.
        angle, velocity: ``(n,)`` the head joint's (joint 1) encoder: rad, rad/s.
        head: ``(n, 2)`` the camera's position on the floor, m.
        com: ``(n, 2)`` the centre of mass on the floor, m.
        steps_per_period: control steps in a gait period.
    """

    t: np.ndarray
    angle: np.ndarray
    velocity: np.ndarray
    head: np.ndarray
    com: np.ndarray
    steps_per_period: int


def straight_run(periods: float = 4.0, *, gait: GaitParams | None = None, phase: float = 0.0, physics=None) -> Run:
    """The snake slithering straight (no steering, head compensation on) for ``periods`` gait periods.

    Args:
        periods: length, gait periods (> 0).
        gait: default `robots.snake.gait.gait_params`.
        phase: added to the gait's time (s), to start at another point of the wave.
        physics: a `robots.snake.physics.SnakePhysics` (default the C backend).
    """
    from robots.snake.physics import make_physics

    if not periods > 0:
        raise UserError(f"a straight run needs periods > 0, not {periods}")
    gait = gait_params() if gait is None else gait
    phys = make_physics("mujoco") if physics is None else physics
    dt = phys.dt * phys.substeps
    per = int(round(float(gait_period(gait)) / dt))
    n = int(round(periods * per))
    model = phys.mj_model
    joint = model.joint("joint1")
    qadr, vadr = int(model.jnt_qposadr[joint.id]), int(model.jnt_dofadr[joint.id])

    def body(state, _):
        state = phys.step(state, joint_targets(gait, state.time + phase))
        return state, (state.time, state.qpos[qadr], state.qvel[vadr], state.head_pos[:2], state.com_pos[:2])

    _, out = jax.jit(lambda s: jax.lax.scan(body, s, None, length=n))(phys.init())
    t, angle, velocity, head, com = (np.asarray(v, np.float64) for v in out)
    return Run(t, angle, velocity, head, com, per)


def _centred_mean(x: np.ndarray, window: int) -> np.ndarray:
    """Moving mean over ``window`` samples centred on each (shrinking at the ends)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    i = np.arange(len(x))
    lo, hi = np.maximum(i - window // 2, 0), np.minimum(i + window - window // 2, len(x))
    return ((c[hi] - c[lo]).T / (hi - lo)).T


REFERENCES = ("camera", "com")


def true_offset(run: Run, reference: str = "camera") -> np.ndarray:
    """The camera's lateral offset from the central line, m, positive to the right, ``(n,)``.

    The central line is a path averaged over one gait period (a centred
    moving mean), its direction that of the path averaged once more:

    * ``"camera"`` (default): the camera's own path. The offset is then the
      camera's swing about its mean path, what Eq. (6) models.
    * ``"com"``: the centre of mass's path. The camera's mean offset from it
      wanders by about +-2 cm from one period to the next (the body's mean
      shape is not steady), which no function of the head joint predicts.

    Valid away from the run's first and last half period.
    """
    if reference not in REFERENCES:
        raise UserError(f"reference must be one of {', '.join(REFERENCES)}, not {reference!r}")
    line = _centred_mean(run.head if reference == "camera" else run.com, run.steps_per_period)
    direction = np.gradient(_centred_mean(line, run.steps_per_period), axis=0)
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    right = np.stack([direction[:, 1], -direction[:, 0]], axis=1)
    return np.sum((run.head - line) * right, axis=1)


def estimate(swing: SwingFit, angle, velocity) -> np.ndarray:
    """Eqs. (5)-(6) on the mean-filtered encoder signals (``swing.window`` steps): the estimated offset, m."""
    a = pp.causal_mean(angle, swing.window)
    v = pp.causal_mean(velocity, swing.window)
    return np.asarray(
        pp.camera_offset(
            jnp.asarray(a, jnp.float32),
            jnp.asarray(v, jnp.float32),
            swing.swing_amplitude,
            swing.swing_ratio,
            swing.swing_phase,
            swing.omega,
        ),
        np.float64,
    )


def _amplitude_for(phase, a, v, ratio, omega, y):
    """The least-squares ``A`` and residual for ``phi_pos = phase``: ``y ~ A sin(alpha (...))``."""
    basis = np.sin(ratio * (a * np.cos(phase) + v / omega * np.sin(phase)))
    amplitude = float(basis @ y / max(basis @ basis, 1e-12))
    return amplitude, float(np.mean((y - amplitude * basis) ** 2))


def whole_periods(run: Run) -> slice:
    """The steps `fit` uses: whole gait periods after the first (the start-up), short of the last half period
    (where the central line of `true_offset` runs out)."""
    per = run.steps_per_period
    return slice(per, per + ((len(run.t) - per - per // 2) // per) * per)


def fundamental_coefficient(t: np.ndarray, y: np.ndarray, omega: float) -> complex:
    """``c`` with ``y``'s component at ``omega`` equal to ``Re(c e^{i omega t})`` (its FFT bin over whole periods)."""
    return complex(2.0 * np.mean(y * np.exp(-1j * omega * t)))


def fit(run: Run, window: int = WINDOW, omega: float | None = None) -> SwingFit:
    """Fit ``(A, alpha, phi_pos)`` of Eqs. (4)-(6) to a straight run (see the module's notes).

    Args:
        run: from `straight_run`, at least 3 gait periods (the first and the
            last half are left out: the start-up and the central line's ends).
        window: the mean filter's window, control steps (>= 1).
        omega: the gait's angular frequency, rad/s (default from the run's period).

    Returns:
        A `SwingFit`.
    """
    per = run.steps_per_period
    if len(run.t) < 3 * per:
        raise UserError(f"the fit needs a run of at least 3 gait periods ({3 * per} steps), not {len(run.t)} steps")
    if not (isinstance(window, int) and window >= 1):
        raise UserError(f"the mean filter's window must be a positive integer of steps, not {window!r}")
    dt = float(run.t[1] - run.t[0])
    omega = 2 * math.pi / (per * dt) if omega is None else float(omega)
    used = whole_periods(run)
    # Eq. (4): the fundamental of the head joint over whole periods (its FFT bin at omega).
    a = float(abs(fundamental_coefficient(run.t[used], run.angle[used], omega)))
    ratio = 0.5 * math.pi / a
    angle = pp.causal_mean(run.angle, window)[used]
    velocity = pp.causal_mean(run.velocity, window)[used]
    y = true_offset(run)[used]
    grid = np.radians(np.arange(-180.0, 180.0, 0.5))
    errors = [_amplitude_for(p, angle, velocity, ratio, omega, y)[1] for p in grid]
    best = float(grid[int(np.argmin(errors))])
    lo, hi = best - math.radians(0.5), best + math.radians(0.5)
    g = (math.sqrt(5) - 1) / 2
    for _ in range(40):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if (
            _amplitude_for(m1, angle, velocity, ratio, omega, y)[1]
            < _amplitude_for(m2, angle, velocity, ratio, omega, y)[1]
        ):
            hi = m2
        else:
            lo = m1
    phase = 0.5 * (lo + hi)
    amplitude, mse = _amplitude_for(phase, angle, velocity, ratio, omega, y)
    if amplitude < 0:  # (A, phi_pos) and (-A, phi_pos + pi) are the same swing: keep A > 0
        amplitude, phase = -amplitude, phase + math.pi
    phase = (phase + math.pi) % (2 * math.pi) - math.pi
    return SwingFit(amplitude, ratio, phase, omega, a, window, math.sqrt(mse))


def calibrate(periods: float = 4.0, window: int = WINDOW, **run_kw) -> SwingFit:
    """`fit` of a `straight_run` of ``periods`` gait periods: this snake's ``(A, alpha, phi_pos)``."""
    return fit(straight_run(periods, **run_kw), window)
