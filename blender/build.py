"""Packs the add-on as a Blender 4.2+ extension zip (its manifest at the zip's root):
`python3 blender/build.py [OUT.zip]` (default target/tilefarm_blender.zip). Install it
in Blender with Edit > Preferences > Get Extensions > Install from Disk."""

import os
import sys
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
PACKAGE = os.path.join(HERE, "tilefarm_blender")


def build(out):
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for name in sorted(os.listdir(PACKAGE)):
            path = os.path.join(PACKAGE, name)
            if os.path.isfile(path) and (name.endswith(".py") or name == "blender_manifest.toml"):
                z.write(path, name)
    return out


if __name__ == "__main__":
    target = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "target", "tilefarm_blender.zip")
    print(build(target))
