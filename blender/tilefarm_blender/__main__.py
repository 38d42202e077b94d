"""Headless export: `python -m tilefarm_blender OUT_DIR [--blend FILE] [--frame N]`
with PyPI's `bpy` (in Blender itself: `cli.run_from_blender`). Prints the one warning
of what was not mapped."""

import sys

from .cli import main

sys.exit(main(sys.argv[1:]))
