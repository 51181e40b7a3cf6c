"""Write the arm meshes ur_rg2_sim ships: each UR link's collision STL as OBJ with normals.

The sources are the installed example-robot-data's ``ur_description`` collision meshes; the
files go to ``ros2_ws/src/ur_rg2_sim/meshes/MODEL/LINK.obj``, which ``setup.py`` installs into
the package's share directory (``meshes/PROVENANCE.md`` says where they come from and their
licence). Run again only when example-robot-data or the conversion changes; a test checks that
the shipped files are what this writes. Usage: ``python scripts/robot_meshes.py``
"""

from pathlib import Path
import sys

from ur_rg2_sim.robot_model import MESHES, ROBOT_MODELS, convert_meshes

TARGET = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src' / 'ur_rg2_sim' / MESHES


def main() -> int:
    """Write every robot model's meshes under TARGET, replacing the old ones."""
    for model in ROBOT_MODELS:
        directory = TARGET / model
        directory.mkdir(parents=True, exist_ok=True)
        for old in directory.glob('*.obj'):
            old.unlink()
        files = convert_meshes(model, directory)
        size = sum(file.stat().st_size for file in files)
        print(f'{model}: {len(files)} meshes, {size / 1e6:.2f} MB in {directory}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
