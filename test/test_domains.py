"""Test runs can be isolated: ROS_DOMAIN_ID from the environment decides the tests' domains."""
from domains import ros_domain, ros_domains
import pytest


def test_ros_domain_id_from_the_environment_wins(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    assert ros_domain(base=20, spread=80) == 42
    assert list(ros_domains(5, base=100, spread=25)) == [42, 43, 44, 45, 46]


def test_without_it_the_pid_picks_and_bad_ids_are_refused(monkeypatch):
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    assert 20 <= ros_domain(base=20, spread=80) < 100
    first = ros_domains(5, base=100, spread=25)[0]
    assert 100 <= first < 225 and (first - 100) % 5 == 0
    monkeypatch.setenv('ROS_DOMAIN_ID', '230')
    with pytest.raises(ValueError, match='DDS allows 0..232'):
        ros_domains(5, base=100, spread=25)
