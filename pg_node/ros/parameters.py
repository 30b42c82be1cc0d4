"""
A node's ROS parameters from pg_node's table: declared with their limits, changed live or refused.

Every parameter is declared with a ``ParameterDescriptor`` that ``ros2 param describe`` shows:
its meaning and allowed values (``description``, ``additional_constraints``), its range
(``integer_range`` / ``floating_point_range``) and whether it is ``read_only``. The table
(:mod:`pg_node.common.params`) marks the parameters that may change while the node runs
(``live``); ``ros2 param set`` of one of them goes through the same check as at start-up
(refused with the reason otherwise) and is then applied by the node's ``on_change``. Every
other parameter is read-only, so ROS itself refuses the change instead of storing a value the
node would never use.
"""
import math
import sys
from typing import Any, Callable, Dict, Optional

from pg_node.common.param_schema import ConfigError, Param
from pg_node.common.params import known_keys
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

#: Parameters every rclpy node may be given besides pg_node's own.
ROS_KEYS = {'use_sim_time', 'start_type_description_service'}


def descriptor(param: Param) -> ParameterDescriptor:
    """Return the descriptor of one table entry: meaning, allowed values, range, read-only."""
    when = 'can change at run time' if param.live else 'read-only: set at start-up'
    desc = ParameterDescriptor(description=f'{param.description} ({when})',
                               additional_constraints=param.allowed(),
                               read_only=not param.live)
    if (param.low is None and param.high is None) or param.choices is not None:
        return desc
    if type(param.default) is int:
        desc.integer_range = [IntegerRange(
            from_value=-sys.maxsize - 1 if param.low is None else math.ceil(param.low),
            to_value=sys.maxsize if param.high is None else math.floor(param.high), step=1)]
    elif type(param.default) is float:
        # an exclusive lower bound (learning rates > 0) is checked by the table; the range
        # says the closed interval around it
        desc.floating_point_range = [FloatingPointRange(
            from_value=-math.inf if param.low is None else float(param.low),
            to_value=math.inf if param.high is None else float(param.high), step=0.0)]
    return desc


def declare_params(node: Node, table: Dict[str, Param],
                   on_change: Optional[Callable[[str, Any], None]] = None) -> Dict:
    """
    Declare every parameter of ``table`` on ``node`` and return the checked values.

    Raises :class:`~pg_node.common.param_schema.ConfigError` naming the parameter when a value
    given in the parameter file or on the command line is not allowed, or when a parameter given
    there is known to no pg_node node (a typo: ROS would silently ignore it). A key that
    another node reads is accepted, as a shared parameter file gives every node all of them.

    The returned dict stays the node's view of its parameters: a live change accepted by
    ``ros2 param set`` is written into it, then ``on_change(name, value)`` is called (the
    node applies what it does not read from the dict at each use).
    """
    overrides = getattr(node, '_parameter_overrides', {})
    allowed = known_keys() | set(table) | ROS_KEYS
    for name in sorted(overrides):
        if name not in allowed and not name.startswith('qos_overrides.'):
            raise ConfigError(f"unknown parameter '{node.get_name()}.{name}'; allowed: "
                              f'{", ".join(table)}')
    values = {}
    for name, param in table.items():
        key = f'{node.get_name()}.{name}'
        desc = descriptor(param)
        try:
            node.declare_parameter(name, param.default, desc)
        except InvalidParameterTypeException:
            # a value of another type than the default's (n_steps:=eight, gamma:=1): say
            # what is allowed, or take it where the table converts it (an int for a float)
            value = param.check(key, overrides[name].value)
            node.declare_parameter(name, value, desc, ignore_override=True)
        except InvalidParameterValueException:
            param.check(key, overrides[name].value)     # out of range: raises, naming it
            raise
        values[name] = param.check(key, node.get_parameter(name).value)

    def check(params) -> SetParametersResult:
        for p in params:
            if p.name in table:
                try:
                    table[p.name].check(f'{node.get_name()}.{p.name}', p.value)
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply(params) -> None:
        for p in params:
            if p.name in table:
                old = values[p.name]
                values[p.name] = table[p.name].check(p.name, p.value)
                if on_change is not None:
                    on_change(p.name, values[p.name])
                node.get_logger().info(f'parameter {p.name}: {old!r} -> {values[p.name]!r}')

    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(apply)
    return values
