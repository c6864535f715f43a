"""The planar RoboBee of the RoboBee paper: its physics, the LQR teacher and the SNN that learns to fly it.

- `robots.robobee.params`: `RoboBeeParams`, the robot's traced physical
  parameters (`robobee_params`, `randomize` for domain randomisation).
- `robots.robobee.dynamics`: Eq. (1)-(5) of the RoboBee paper (`rhs`) and the
  actuators' limits (`clip_controls`); the frame and sign conventions.
- `robots.robobee.physics`: the MJCF model stepped by MJX (`physics_step`),
  one robot per call, batched by ``jax.vmap``.
- `robots.robobee.lqr`: the teacher, an LQR on the lateral state
  (`lateral_gain`, `lateral_lqr`) and a PD altitude controller
  (`altitude_params`, `altitude_control`).
- `robots.robobee.controller`: the 200-100-50 LIF controller of Sec. III
  (`ControllerConfig`, `controller_params`, `controller_init`,
  `controller_step`), trained online by Eq. (9)-(10).
- `robots.robobee.flight`: the closed loop of Sec. V as one ``lax.scan``
  (`fly`, `flight_plan`).
- `robots.robobee.trial`: the flight trial that sweep files name (`flight_trial`).
- `robots.robobee.reproduce`: ``spikejax reproduce robobee`` and its siblings.
- `robots.robobee.bench`, `robots.robobee.bench_network`: ``spikejax bench
  robobee`` and ``robobee-network``.
"""
