"""
The kinematics check's tolerance: a calibrated arm's description is refused or taken by it.

:func:`pg_node.sim.kinematics_check.compare_kinematics` on reacher2's URDF with joint1 moved
by 20 mm, as a calibration moves a UR's joints by millimetres to centimetres
(``ur_calibration``): the refusal gives the deviation measured and the tolerance, and a
tolerance above the deviation takes the description.
"""
from pathlib import Path

import mujoco
from pg_node.common.paths import resolve_model
from pg_node.sim.kinematics_check import compare_kinematics, TOLERANCE
import pytest

URDF = (Path(__file__).parent / 'fixtures' / 'reacher2.urdf').read_text()
REACHER = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
MOVED = URDF.replace('xyz="0.1 0 0"', 'xyz="0.12 0 0"')        # joint1 20 mm further out


def test_the_refusal_gives_the_measured_deviation_and_the_tolerance():
    got = compare_kinematics(REACHER, MOVED)
    assert got.startswith("joint joint1 is 20.0 mm away from where the policy's model has it")
    assert got.endswith(f'kinematics_tolerance {1000 * TOLERANCE:g} mm)'), got


@pytest.mark.parametrize('tolerance,taken', [(0.019, False), (0.021, True), (0.05, True)])
def test_a_larger_tolerance_takes_a_calibrated_description(tolerance, taken):
    got = compare_kinematics(REACHER, MOVED, tolerance=tolerance)
    assert (got is None) == taken, got
    if not taken:
        assert '20.0 mm away' in got and f'kinematics_tolerance {1000 * tolerance:g} mm' in got
