"""Complete ``ros2msg`` message definitions, as rosbag2 stores them as MCAP schemas.

rosbag2 (rosbag2_cpp's LocalMessageDefinitionSource) reads the type's ``.msg`` file from its
package's share directory and appends each type it uses, recursively and once, after a
delimiter line of 80 ``=`` and a line ``MSG: package/Type`` (the name as the field spells it).
Readers without the message packages (Foxglove, Lichtblick, Rerun, mcap_ros2) decode with it.
No ROS imports: the share directories come from the ament index.
"""

from collections.abc import Callable
from pathlib import Path
import re

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

DELIMITER = '=' * 80 + '\n'
# A field's type at the start of a line ("std_msgs/Header" of "std_msgs/Header header",
# "Point" of "Point[] points"): the expression rosbag2 uses.
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                         'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'})
_MAX_DEPTH = 50


class DefinitionNotFoundError(LookupError):
    """No ``.msg`` file for a type (its package is not installed, or the name is not a type)."""


def msg_file(type_name: str) -> Path:
    """Return the ``.msg`` file of ``pkg/msg/Type`` or ``pkg/Type`` from the ament index."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts.insert(1, 'msg')
    if len(parts) != 3 or not all(parts):
        raise DefinitionNotFoundError(f'{type_name!r} is not a message type name')
    package, folder, name = parts
    try:
        share = Path(get_package_share_directory(package))
    except (PackageNotFoundError, ValueError) as error:
        raise DefinitionNotFoundError(f'no package {package!r} for {type_name}') from error
    path = share / folder / f'{name}.msg'
    if not path.is_file():
        raise DefinitionNotFoundError(f'no {path}')
    return path


def dependencies(text: str, package: str) -> list[str]:
    """Return the non-primitive field types of a ``.msg`` text, sorted, with their package."""
    found = set()
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in _PRIMITIVES:
            continue
        found.add(name if '/' in name else f'{package}/{name}')
    return sorted(found)


def full_text(type_name: str,
              read: Callable[[str], str] = lambda name: msg_file(name).read_text()) -> str:
    """Return the complete ``ros2msg`` definition of ``type_name`` (e.g. sensor_msgs/msg/Image).

    ``read`` returns the ``.msg`` text of a type name; by default from the ament index.
    """
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise DefinitionNotFoundError(f'definition of {type_name} nests too deeply')
        text = read(name)
        result = text
        for dependency in dependencies(text, name.split('/')[0]):
            if dependency not in seen:
                seen.add(dependency)
                result += '\n' + DELIMITER + f'MSG: {dependency}\n' + append(dependency,
                                                                            depth - 1)
        return result

    return append(type_name, _MAX_DEPTH)
