"""
policy_node follows the robot's own state as a UR's driver publishes it, as a process over DDS.

Universal_Robots_ROS2_Driver (jazzy a16a2687) publishes, among its std_msgs topics:
``io_and_status_controller``'s ``~/robot_program_running`` (``std_msgs/Bool``, reliable and
transient local, sent when it changes: ur_controllers/src/gpio_controller.cpp:249-251,
265-266, 365-368) and ``speed_scaling_state_broadcaster``'s ``~/speed_scaling``
(``std_msgs/Float64``, system-default QoS, the speed scaling factor x 100, at
``state_publish_rate``: ur_controllers/src/speed_scaling_state_broadcaster.cpp:111-112,
136-141). ``robot_mode`` and ``safety_mode`` are ur_dashboard_msgs, not followed.

The test plays that driver: no message yet, the program running, a protective stop (speed
scaling 0), the program stopped and started again; policy_node holds across each stop, says
why in /diagnostics and once in its log, and commands again after ramping in from the hold.
"""
from pg_node.tools import processes
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from repeating import repeating
from std_msgs.msg import Bool, Float64
from test_lifecycle_cli import policy  # noqa: F401 - the fixture: an untrained ONNX policy
from test_policy_node import Client, PLAIN, start_policy

pytestmark = pytest.mark.e2e
PROGRAM = '/io_and_status_controller/robot_program_running'
SPEED = '/speed_scaling_state_broadcaster/speed_scaling'
#: as gpio_controller.cpp:249-251 offers it
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def client():
    c = Client()
    yield c
    c.close()


def test_the_robots_own_stop_holds_then_ramps_in(tmp_path, client, policy):  # noqa: F811
    program = client.node.create_publisher(Bool, PROGRAM, LATCHED)
    speed = client.node.create_publisher(Float64, SPEED, 10)
    scaling = {'percent': None}

    def drive():
        client.send_state(PLAIN, (0.3, -1.2), (0.0, 0.0))
        if scaling['percent'] is not None:
            speed.publish(Float64(data=scaling['percent']))

    def diag():
        with client.lock:
            return client.diagnostics[-1] if client.diagnostics else ('', {})

    def wait_for(words, what, **counts):
        def seen():
            message, values = diag()
            return words in message and all(values.get(k) == str(v) for k, v in counts.items())
        client.wait(seen, what=what)
        return diag()[1]

    pol = start_policy(tmp_path, f'policy:={policy}', 'state_timeout:=5.0', 'ramp_time:=0.3',
                       'diagnostics_rate:=20.0', f'robot_program_running_topic:={PROGRAM}',
                       f'speed_scaling_topic:={SPEED}')
    try:
        with repeating(drive, 50.0):
            client.send_target('', [0.1, 0.1, 0.01])
            # nothing from the driver yet: hold, saying which topic is silent
            values = wait_for(f'robot stopped: no message yet on {PROGRAM}', 'the first hold',
                              robot_stops=1)
            assert values['robot_program_running'] == 'no message yet'
            program.publish(Bool(data=True))
            wait_for(f'robot stopped: no message yet on {SPEED}', 'the speed scaling topic')
            scaling['percent'] = 100.0
            values = wait_for('commanding', 'commanding', robot_stops=1)
            assert values['robot_program_running'] == 'true'
            assert values['speed_scaling'] == '100.0'
            ramped = int(values['guard_ramped'])
            assert ramped > 0
            # a protective stop: speed scaling 0 holds; back at 100 ramps in again
            scaling['percent'] = 0.0
            held = int(wait_for(f'robot stopped: speed scaling 0 % on {SPEED} (a protective '
                                'stop or a pause): hold command', 'the protective stop',
                                robot_stops=2)['hold_commands'])
            wait_for('robot stopped', 'more holds', hold_commands=held + 5)
            scaling['percent'] = 100.0
            values = wait_for('commanding', 'commanding after the protective stop')
            assert int(values['guard_ramped']) > ramped
            ramped = int(values['guard_ramped'])
            # the program stopped, then started again
            program.publish(Bool(data=False))
            wait_for(f'robot stopped: its program is not running ({PROGRAM} false)',
                     'the program stopped', robot_stops=3)
            program.publish(Bool(data=True))
            values = wait_for('commanding', 'commanding after the restart')
            assert int(values['guard_ramped']) > ramped and values['level'] == 0
    finally:
        code, log = processes.stop_logged(pol)
    assert code == 0, log[-2000:]
    stops = [line for line in log.splitlines() if '[WARN]' in line and 'robot stopped' in line]
    assert len(stops) == 3, log                  # once per spell
    assert log.count('the robot runs again: commanding, ramping in from the hold') == 3, log
