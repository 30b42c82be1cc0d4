"""
The files generated from the node tables: docs/ros_graph.md's table, config/policy_node.yaml.

Tests keep each generated file equal to what this module writes today; run it
(``python -m pg_node.tools.param_docs``) to write config/policy_node.yaml.
"""
import textwrap
from typing import Dict

from pg_node.common.param_schema import Param
from pg_node.common.params import POLICY_PARAMS, SCHEMA, SHARED, SHARED_PARAMS
import yaml


def markdown_table() -> str:
    """
    Return every node's parameters as a Markdown table (docs/ros_graph.md's, kept equal by a test).

    Columns: node (``/**`` for the shared ones), name, default, allowed values, and whether
    ``ros2 param set`` can change it while the node runs (live) or is refused (read-only).
    """
    rows = ['| node | parameter | default | allowed | at run time | meaning |',
            '|---|---|---|---|---|---|']
    for section, table in [(SHARED, SHARED_PARAMS), *SCHEMA.items()]:
        for name, p in table.items():
            rows.append(f'| `{section}` | `{name}` | `{p.default!r}` | {p.allowed()} | '
                        f'{"live" if p.live else "read-only"} | {p.description} |')
    return '\n'.join(rows)


#: the one-line command that writes config/policy_node.yaml from :data:`POLICY_PARAMS`
POLICY_FILE_COMMAND = 'python -m pg_node.tools.param_docs > config/policy_node.yaml'
#: what the shipped file says beside a parameter that has no useful default
POLICY_FILE_NOTES = {
    'policy': "REQUIRED: policy_node refuses to start with it empty. Put your policy's path "
              'here, or give it at start: policy:=PATH (ros2 launch pg_node '
              'deploy.launch.py), -p policy:=PATH (ros2 run pg_node policy_node --ros-args)',
}


def yaml_value(value) -> str:
    """
    Return ``value`` as a YAML flow scalar or list, quoted only where YAML needs it.

    >>> [yaml_value(v) for v in ('', 'effort', '0.01', True, 0.2, 3, [64, 64])]
    ["''", 'effort', "'0.01'", 'true', '0.2', '3', '[64, 64]']
    """
    text = yaml.safe_dump(value, default_flow_style=True, width=1000)
    return text.removesuffix('\n...\n').strip()


def parameter_file(node: str, table: Dict[str, Param], header: str, notes=None,
                   width: int = 99) -> str:
    """
    Return a ROS 2 parameter file of one node: every parameter at its default, explained.

    The section is ``/**/<node>``, which reaches the node in any namespace. Above each key,
    as comments: its meaning, its allowed values and whether ``ros2 param set`` may change it
    while the node runs (live) or not (read-only); then ``notes[key]``, if any.
    """
    notes = notes or {}
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    lines += [f'/**/{node}:', '  ros__parameters:']
    for key, p in table.items():
        at_run_time = 'live (ros2 param set)' if p.live else 'read-only'
        text = f'{p.description}. Allowed: {p.allowed()}; {at_run_time}.'
        for part in (text, notes.get(key)):
            if part:
                lines += textwrap.wrap(part, width, initial_indent='    # ',
                                       subsequent_indent='    # ', break_on_hyphens=False)
        lines.append(f'    {key}: {yaml_value(p.default)}')
    return '\n'.join(lines) + '\n'


def policy_node_file() -> str:
    """Return config/policy_node.yaml: :data:`POLICY_PARAMS` at their defaults, explained."""
    header = (
        "policy_node's parameters in ROS 2's parameter-file format, each at its default "
        'with its\nmeaning, allowed values and whether it may change while the node runs. '
        'The key\n/**/policy_node reaches policy_node in any namespace (namespace:= of '
        'deploy.launch.py,\n-r __ns:=). Copy this file, edit it and give it to '
        'launch/deploy.launch.py\n(params_file:=) or to ros2 run pg_node policy_node '
        '--ros-args --params-file FILE.\n\nGenerated from pg_node/common/params.py '
        '(POLICY_PARAMS); a test keeps it equal. Regenerate:\n  ' + POLICY_FILE_COMMAND)
    return parameter_file('policy_node', POLICY_PARAMS, header, POLICY_FILE_NOTES)


if __name__ == '__main__':
    print(policy_node_file(), end='')
