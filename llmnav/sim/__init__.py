"""The PyBullet simulation: world, robot, sensors and motion. It knows nothing of LLMs."""

import os
import sys


def _import_pybullet_quietly() -> None:
    """Import pybullet with stderr closed for a moment.

    It prints its build time on import: before every error message, and once per worker process.
    """
    if "pybullet" in sys.modules:
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real stderr (embedded, test capture): import as is
        # as is: there is no stderr to close
        import pybullet  # noqa: F401

        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        # here, not at the top: stderr is closed around the import to hide pybullet's banner
        import pybullet  # noqa: F401
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


_import_pybullet_quietly()
