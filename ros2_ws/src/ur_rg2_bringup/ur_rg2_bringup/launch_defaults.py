"""Defaults of graph.launch.py's arguments that depend on other arguments, as substitutions.

An argument that sets a node's parameter (``robot_model``, ``detector``, ``port`` ...) takes,
when it is not given, the value the parameters file gives that parameter, so that a file passed
as ``params_file:=FILE`` works as it is; and its own default when the file has none. The 3D
view's port is the viewer's + 1 unless set, so that the two pages never collide by default.
"""

from __future__ import annotations

from pathlib import Path
import re
from typing import Any

from launch import LaunchContext, SomeSubstitutionsType, Substitution
from launch.substitutions import LaunchConfiguration, SubstitutionFailure
from launch.utilities import normalize_to_list_of_substitutions, perform_substitutions
import yaml

MAX_PORT = 65535


def _matches(pattern: str, node: str) -> bool:
    """Tell whether a parameters file's section name (``/**/name``, ``/ns/name``) is ``node``.

    ``node`` is the node's full name (``/name`` or ``/ns/name``); ``/**`` stands for any
    namespaces (none too) and ``*`` for one name, as rcl reads them.
    """
    pattern = pattern if pattern.startswith('/') else '/' + pattern
    regex = re.escape(pattern).replace(r'/\*\*', '(?:/[^/]+)*').replace(r'\*', '[^/]+')
    return re.fullmatch(regex, node) is not None


def file_parameter(path: str | Path, node: str, name: str) -> Any:
    """Return what the ROS parameters file ``path`` sets ``node``'s ``name`` to, None if nothing.

    ``node`` is the node's full name; the last section that matches it and sets ``name`` wins.
    Raises ValueError, saying why, when the file cannot be read or is no parameters file.
    """
    try:
        document = yaml.safe_load(Path(path).read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        reason = getattr(error, 'strerror', None) or str(error).splitlines()[0]
        raise ValueError(f'params_file {path}: cannot be read: {reason}') from None
    if document is None:
        return None
    if not isinstance(document, dict):
        raise ValueError(f'params_file {path}: not a parameters file (no node sections)')
    value = None
    for pattern, section in document.items():
        parameters = section.get('ros__parameters') if isinstance(section, dict) else None
        if isinstance(parameters, dict) and name in parameters and _matches(str(pattern), node):
            value = parameters[name]
    return value


def as_argument(value: Any) -> str:
    """Return a parameter's value as a launch argument's text (``true``, ``30.0``, ``ur3``)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def next_port(port: str) -> str:
    """Return the port after ``port`` (a launch argument's text); 0 (any free port) stays 0.

    Raises ValueError for text that is no port number.
    """
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= MAX_PORT:
        raise ValueError(f'port:={port} is no port number (0-{MAX_PORT})')
    return '0' if number in (0, MAX_PORT) else str(number + 1)


class FileParameter(Substitution):
    """A node's parameter as the graph's parameters file sets it, else a default."""

    def __init__(self, node: str, name: str, default: SomeSubstitutionsType,
                 params_file: SomeSubstitutionsType) -> None:
        super().__init__()
        self._node = node
        self._name = name
        self._default = normalize_to_list_of_substitutions(default)
        self._params_file = normalize_to_list_of_substitutions(params_file)

    def describe(self) -> str:
        """Say what the default is, for ``--show-args``."""
        default = ' + '.join(part.describe() for part in self._default)
        return f"{self._node}'s {self._name} in params_file, else {default}"

    def perform(self, context: LaunchContext) -> str:
        """Return the file's value of the parameter, or the default's."""
        namespace = LaunchConfiguration('namespace', default='').perform(context).strip('/')
        node = '/'.join(['', *([namespace] if namespace else []), self._node])
        path = perform_substitutions(context, self._params_file)
        try:
            value = file_parameter(path, node, self._name)
        except ValueError as error:
            raise SubstitutionFailure(str(error)) from None
        if value is None:
            return perform_substitutions(context, self._default)
        return as_argument(value)


class NextPort(Substitution):
    """The port after another argument's port (0 stays 0: any free port)."""

    def __init__(self, port: SomeSubstitutionsType) -> None:
        super().__init__()
        self._port = normalize_to_list_of_substitutions(port)

    def describe(self) -> str:
        """Say what the default is, for ``--show-args``."""
        port = ' + '.join(part.describe() for part in self._port)
        return f'{port} + 1 (0: any free port)'

    def perform(self, context: LaunchContext) -> str:
        """Return the next port's number as text."""
        try:
            return next_port(perform_substitutions(context, self._port))
        except ValueError as error:
            raise SubstitutionFailure(str(error)) from None

