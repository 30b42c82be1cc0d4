"""
The DDS domains of a test process: ``ROS_DOMAIN_ID`` from the environment when it is set.

Set it to isolate a test run on a shared machine (``ROS_DOMAIN_ID=42 make test``): a test file
that needs one domain uses that id, one that needs ``count`` isolated domains uses it and the
ids after it. Unset, each file picks ids from the test process's pid, as before.
"""
import os


def ros_domains(count: int, base: int, spread: int) -> range:
    """
    Return ``count`` consecutive domain ids.

    From ``ROS_DOMAIN_ID`` when set, else from ``base + (pid % spread) * count``.
    """
    given = os.environ.get('ROS_DOMAIN_ID', '').strip()
    start = int(given) if given else base + (os.getpid() % spread) * count
    if not 0 <= start <= 232 - count + 1:
        raise ValueError(f'ROS_DOMAIN_ID {start}: tests need ids {start}..{start + count - 1}, '
                         f'and DDS allows 0..232')
    return range(start, start + count)


def ros_domain(base: int, spread: int) -> int:
    """Return one domain id: ``ROS_DOMAIN_ID`` when set, else ``base + pid % spread``."""
    return ros_domains(1, base, spread)[0]
