"""The wheel-less snake robot of the snake papers: MJCF model, slithering gait, physics backends, the task.

- `robots.snake.gait`: Eq. (1) of the snake R-STDP paper (`GaitParams`,
  `gait_params`, `joint_targets`), steering by ``C_o`` and head compensation.
- `robots.snake.physics`: `make_physics` (``"mujoco"``: MuJoCo's C engine,
  threaded, inside the jitted program; ``"mjx"``: one XLA program), one snake
  per call, batched by ``jax.vmap``.
- `robots.snake.tracks`: the target's tracks of Fig. 5, its motion rule and the
  angles of Eq. (12).
- `robots.snake.camera`: the head camera's pose and the scene it renders.
- `robots.snake.env`: the target-tracking task as a Brax ``Env`` (`SnakeEnv`,
  with its sweepable quantities traced in `SnakeEnvParams`).
- `robots.snake.steering`: a scripted steering baseline (`init`, `step`).
- `robots.snake.reproduce`: ``spikejax reproduce snake-gait``.
- `robots.snake.bench`: ``spikejax bench snake``.
"""
