"""The robots spikejax controls: the hexapod, the RoboBee and the snake, each an env in the Brax shape.

Importing MJX prints a line to stdout when its optional Warp backend is not
installed (it never is here: the robots run on MuJoCo C or MJX's JAX
backend), once per process; the import below keeps it out of the output of
every command and script that uses a robot.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    import mujoco.mjx  # noqa: F401
