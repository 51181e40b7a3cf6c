"""Static objects on the floor that are not balls (the sim's ``scene_objects``). No pybullet.

Cubes, boxes and flat discs for detector data sets and tests, read from and written as the
parameter's text, so that the data set command (which does not load the physics) plans them.
"""

from dataclasses import dataclass
import math


@dataclass(frozen=True)
class SceneObject:
    """A static object standing on the floor that is not a ball: a cube, a box, a flat disc."""

    shape: str  # 'box' or 'disc'
    x: float  # world, m
    y: float
    yaw: float  # rad
    size: tuple[float, float, float]  # half extents (box); radius, unused, half height (disc)
    color: tuple[float, float, float]  # rgb 0-1

    @classmethod
    def parse(cls, text: str) -> list['SceneObject']:
        """Read the sim's ``scene_objects``; ValueError naming the bad object.

        Objects separated by ';', each ``box|disc x y yaw size1 size2 size3 r g b``.
        """
        objects = []
        for index, item in enumerate(part for part in text.split(';') if part.strip()):
            words = item.split()
            try:
                if len(words) != 10 or words[0] not in ('box', 'disc'):
                    raise ValueError
                x, y, yaw, *rest = (float(word) for word in words[1:])
            except ValueError:
                raise ValueError(f'scene_objects[{index}] {item.strip()!r}: expected "box|disc '
                                 'x y yaw size1 size2 size3 r g b"') from None
            size, color = tuple(rest[:3]), tuple(rest[3:])
            if not (all(math.isfinite(n) for n in (x, y, yaw))
                    and all(0.001 <= n <= 1.0 for n in size)
                    and all(0.0 <= c <= 1.0 for c in color)):
                raise ValueError(f'scene_objects[{index}]: x, y, yaw must be finite, sizes '
                                 '0.001-1 m, colours 0-1')
            objects.append(cls(words[0], x, y, yaw, size, color))
        return objects

    def text(self) -> str:
        """Return the object as :meth:`parse` reads it."""
        return ' '.join([self.shape] + [f'{n:.4f}' for n in
                                        (self.x, self.y, self.yaw, *self.size, *self.color)])
