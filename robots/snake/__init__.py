"""The wheel-less snake robot of the snake papers: MJCF model, slithering gait, physics backends.

- `robots.snake.gait`: Eq. (1) of the snake R-STDP paper (`GaitParams`,
  `joint_targets`), steering by ``C_o`` and head compensation.
- `robots.snake.physics`: `make_physics` (``"mujoco"``: MuJoCo's C engine,
  threaded, inside the jitted program; ``"mjx"``: one XLA program), one snake
  per call, batched by ``jax.vmap``.
- `robots.snake.bench`: ``spikejax bench snake``.
"""
