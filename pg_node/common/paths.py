"""Where pg_node's shared files (config, launch, models) are, from source or installed."""
import os
from pathlib import Path
import xml.etree.ElementTree as ET

PACKAGE_NAME = 'pg_node'
_PACKAGE_DIR = Path(__file__).resolve().parent.parent
#: The folder that holds the ``pg_node`` package: a source checkout, or site-packages.
SOURCE_ROOT = _PACKAGE_DIR.parent
#: The environment variable in which a supervisor (``train``, ``soak``, ``play``, the
#: benchmarks) names itself to the nodes it starts: they stop when it dies
#: (``pg_node.ros.runtime.stop_with_supervisor``, ``pg_node.tools.processes.child_env``).
SUPERVISOR_ENV = 'PG_NODE_SUPERVISOR_PID'


def share_dir() -> Path:
    """
    Return the directory holding ``config/``, ``launch/`` and ``models/``.

    A source checkout (``config/`` beside the ``pg_node/`` package) wins, so that a developer
    always runs what they edit; otherwise the colcon/ament install's
    ``share/pg_node`` is found through ``ament_index_python``.
    """
    if (SOURCE_ROOT / 'config').is_dir() and (SOURCE_ROOT / 'package.xml').is_file():
        return SOURCE_ROOT
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory(PACKAGE_NAME))


def models_dir() -> Path:
    """Return the directory of the MJCF arm models shipped with the package."""
    return _PACKAGE_DIR / 'sim' / 'models'


def default_config() -> Path:
    """Return the path of the default parameter file, ``config/pg_node.yaml``."""
    return share_dir() / 'config' / 'pg_node.yaml'


#: the shipped parameter file that is no training preset: the deployment's (policy_node)
DEPLOY_CONFIG = 'policy_node'


def presets() -> list:
    """Return the names of the shipped training parameter files (``config/<name>.yaml``)."""
    return sorted(p.stem for p in (share_dir() / 'config').glob('*.yaml')
                  if p.stem != DEPLOY_CONFIG)


def preset_names() -> list:
    """
    Return the presets a user picks by name: every shipped file but the defaults' own.

    ``config/pg_node.yaml`` holds every node's defaults (what runs without ``--config``), so
    the help texts list the others; ``--config pg_node`` still works.
    """
    return [name for name in presets() if name != PACKAGE_NAME]


def config_file(name_or_path: str) -> Path:
    """
    Turn a parameter file's path or a preset's name into an existing file path.

    An existing file wins; a bare name such as ``ppo`` (no ``/``, no ``.yaml``) means the
    shipped preset ``config/ppo.yaml``. Raises FileNotFoundError naming the presets otherwise.
    """
    candidate = Path(os.path.expanduser(name_or_path))
    if candidate.is_file():
        return candidate
    if candidate.name == name_or_path and candidate.suffix == '':
        shipped = share_dir() / 'config' / f'{name_or_path}.yaml'
        if shipped.is_file():
            return shipped
    raise FileNotFoundError(
        f'config {name_or_path!r} is neither an existing file nor a preset '
        f'(presets: {", ".join(presets()) or "none"})')


def resolve_model(name_or_path: str) -> Path:
    """Turn a model name (``reacher2``) or an MJCF path into an existing file path."""
    candidate = Path(os.path.expanduser(name_or_path))
    if candidate.suffix == '.xml' and candidate.is_file():
        return candidate
    shipped = models_dir() / f'{name_or_path}.xml'
    if shipped.is_file():
        return shipped
    known = sorted(p.stem for p in models_dir().glob('*.xml'))
    raise FileNotFoundError(
        f'model {name_or_path!r} is neither an existing .xml file nor a shipped model '
        f'(shipped: {", ".join(known) or "none"})')


def check_model(name_or_path: str) -> Path:
    """
    Resolve a model as :func:`resolve_model` does and compile it with MuJoCo; return its path.

    Raises ValueError in one line (MuJoCo's message, its lines joined) when the file is not
    valid MJCF, so that a configuration check refuses it before any node starts. MuJoCo is
    imported here, not with this module.
    """
    path = resolve_model(name_or_path)
    try:
        root = ET.parse(path).getroot().tag
    except (ET.ParseError, OSError):
        root = None                 # MuJoCo says what is wrong with it, below
    if root == 'robot':
        # MuJoCo compiles a URDF too, into a model without actuators: no arm
        raise ValueError(f'{path} is a URDF, not MJCF: make a pg_node arm of it with '
                         f'python -m pg_node arm import {path}')
    import mujoco
    try:
        mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        reason = '; '.join(line.strip() for line in str(exc).splitlines() if line.strip())
        reason = reason.replace(':; ', ': ')
        raise ValueError(f'{path} is not a valid MuJoCo model: {reason}') from None
    return path
