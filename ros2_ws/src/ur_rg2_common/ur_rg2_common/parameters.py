"""Declaring a node's parameters, with integers accepted where a double is declared.

People type ``camera_rate:=15`` or ``ros2 param set /ur_rg2_sim camera_rate 15``; ROS parses
``15`` as an INTEGER and rclpy refuses it for a DOUBLE parameter ("of type 'INTEGER',
expecting type 'DOUBLE'"). Every node of the project declares its parameters here, so that an
integer (or a list of integers) given for a double (or double array) parameter is taken as the
same number, at start-up and at run time, while the parameter stays a double (``ros2 param
describe`` says so). Any other kind (a string for a number) is still refused by rclpy, with
its reason.

Every node declares its parameters the same way: a module-level tuple of :class:`ParameterSpec`
in a plain settings module of its package (each default written once, there), a frozen
dataclass whose ``from_values`` validates the values, ``declare_parameters(node, SPECS)`` at
start-up, and :func:`follow_settings` to keep the dataclass up to date when parameters are set
at run time. The node reads the dataclass, never ``get_parameter``.

Used by every node of the graph, so it lives in the package they all depend on.
"""

from collections.abc import Callable, Iterable, Sequence
from functools import partial
from typing import Any, NamedTuple, Optional, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.node import Node
from rclpy.parameter import Parameter


class ParameterSpec(NamedTuple):
    """One parameter of a node; its default's type is the parameter's type."""

    name: str
    default: Any
    description: str
    read_only: bool = False
    # Inclusive (low, high) for an integer or double parameter, checked by rclpy.
    bounds: Optional[tuple[float, float]] = None

    def descriptor(self) -> ParameterDescriptor:
        """Return the descriptor ``ros2 param describe`` shows for this parameter."""
        descriptor = ParameterDescriptor(description=self.description, read_only=self.read_only)
        if self.bounds is not None:
            low, high = self.bounds
            if isinstance(self.default, int):
                descriptor.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
            else:
                descriptor.floating_point_range = [
                    FloatingPointRange(from_value=float(low), to_value=float(high))]
        return descriptor


def as_declared_type(declared: Parameter.Type, value: Any) -> Any:
    """Return ``value`` as a ``declared``-type value where it is an integer (array) for a double.

    Anything else comes back unchanged (the same object), for rclpy to accept or refuse.
    """
    given = Parameter.Type.from_parameter_value(value)
    if declared is Parameter.Type.DOUBLE and given is Parameter.Type.INTEGER:
        return float(value)
    if declared is Parameter.Type.DOUBLE_ARRAY and given is Parameter.Type.INTEGER_ARRAY:
        return [float(item) for item in value]
    return value


def declare_parameters(node: Node, specs: Iterable[Sequence]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` and return their values, by name.

    Each spec is a :class:`ParameterSpec` or a plain tuple of its fields. Call it once per node,
    before adding the node's own set-parameters callbacks: it also makes run-time changes
    (``set_parameters``, the SetParameters service) take integers for doubles.
    """
    values = {}
    for spec in (ParameterSpec(*row) for row in specs):
        values[spec.name] = _declare(node, spec).value
    node.add_pre_set_parameters_callback(partial(_integers_as_doubles, node))
    return values


Settings = TypeVar('Settings')


def current_values(node: Node, specs: Iterable[Sequence],
                   changes: Iterable[Parameter] = ()) -> dict[str, Any]:
    """Return the values of ``specs`` on ``node`` by name, with ``changes`` (being set) applied."""
    values = {spec[0]: node.get_parameter(spec[0]).value for spec in specs}
    values.update({parameter.name: parameter.value for parameter in changes
                   if parameter.name in values})
    return values


def follow_settings(node: Node, specs: Iterable[Sequence],
                    from_values: Callable[[dict[str, Any]], Settings],
                    apply: Callable[[Settings], None]) -> None:
    """Keep a node's settings in step with parameters set at run time.

    On each set-parameters request, ``from_values`` builds the settings from the values the
    request would leave; a ValueError or TypeError it raises refuses the request with its
    message (logged as a warning), else ``apply`` gets the new settings. Call it after
    :func:`declare_parameters`.
    """
    specs = tuple(specs)

    def on_set(parameters: list[Parameter]) -> SetParametersResult:
        try:
            settings = from_values(current_values(node, specs, parameters))
        except (TypeError, ValueError) as error:
            node.get_logger().warning(f'parameter change rejected: {error}')
            return SetParametersResult(successful=False, reason=str(error))
        apply(settings)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)


def _declare(node: Node, spec: ParameterSpec) -> Parameter:
    try:
        return node.declare_parameter(spec.name, spec.default, spec.descriptor())
    except InvalidParameterTypeException:
        declared = Parameter.Type.from_parameter_value(spec.default)
        if declared not in (Parameter.Type.DOUBLE, Parameter.Type.DOUBLE_ARRAY):
            raise
    # The start-up value (command line, parameter file, parameter_overrides) is of another
    # type. rclpy offers no public read of it, and its pre-set callbacks do not run for
    # declarations: so declare the name without a type for a moment, to read the value, then
    # for good with the value converted (or unchanged, for rclpy to refuse with its reason).
    given = node.declare_parameter(
        spec.name, spec.default, ParameterDescriptor(dynamic_typing=True)).value
    node.undeclare_parameter(spec.name)
    value = as_declared_type(declared, given)
    if value is given:
        return node.declare_parameter(spec.name, spec.default, spec.descriptor())
    return node.declare_parameter(spec.name, value, spec.descriptor(), ignore_override=True)


def _integers_as_doubles(node: Node, parameters: list[Parameter]) -> list[Parameter]:
    """Pre-set callback: convert integer values given for declared double parameters."""
    converted = []
    for parameter in parameters:
        if (parameter.type_ in (Parameter.Type.INTEGER, Parameter.Type.INTEGER_ARRAY)
                and node.has_parameter(parameter.name)):
            declared = Parameter.Type(node.describe_parameter(parameter.name).type)
            value = as_declared_type(declared, parameter.value)
            if value is not parameter.value:
                parameter = Parameter(parameter.name, declared, value)
        converted.append(parameter)
    return converted
