"""
The few ``controller_manager_msgs`` types the tests need, built at test time.

``controller_manager_msgs`` comes with ros2_control and is not on PyPI: on a robot pg_node
imports the installed one (:mod:`pg_node.ros.controller_manager`). CI has no ros2_control,
so these tests write the definitions below (field for field as Jazzy has them, so that the
wire format and the type hash match) and build them with the rosidl generators and
typesupport packages that are on PyPI: the C structs, the Fast DDS typesupport (the venv's
rmw is rmw_fastrtps_cpp), the C typesupport dispatch and the Python bindings, compiled with
gcc into a cache directory keyed by a hash of the definitions, a few seconds once per machine.

The definitions are transcribed from ros2_control, branch jazzy, commit 9ffbf97fd
(controller_manager_msgs/msg/ChainConnection.msg, msg/ControllerState.msg,
srv/ListControllers.srv, srv/SwitchController.srv); comments are left out (they are not
part of the type).
"""
import contextlib
import ctypes
import fcntl
import glob
import hashlib
import io
import os
from pathlib import Path
import shutil
import subprocess
import sys
import sysconfig
import tempfile

PACKAGE = 'controller_manager_msgs'

#: file (relative to the package) -> its definition
DEFINITIONS = {
    # ros2_control jazzy 9ffbf97fd controller_manager_msgs/msg/ChainConnection.msg:1-2
    'msg/ChainConnection.msg': (
        'string name\n'
        'string[] reference_interfaces\n'),
    # ros2_control jazzy 9ffbf97fd controller_manager_msgs/msg/ControllerState.msg:1-13
    'msg/ControllerState.msg': (
        'string name\n'
        'string state\n'
        'string type\n'
        'bool is_async\n'
        'uint16 update_rate\n'
        'string[] claimed_interfaces\n'
        'string[] required_command_interfaces\n'
        'string[] required_state_interfaces\n'
        'bool is_chainable\n'
        'bool is_chained\n'
        'string[] exported_state_interfaces\n'
        'string[] reference_interfaces\n'
        'ChainConnection[] chain_connections\n'),
    # ros2_control jazzy 9ffbf97fd controller_manager_msgs/srv/ListControllers.srv:1-5
    'srv/ListControllers.srv': (
        '---\n'
        'controller_manager_msgs/ControllerState[] controller\n'),
    # ros2_control jazzy 9ffbf97fd controller_manager_msgs/srv/SwitchController.srv:39-51
    'srv/SwitchController.srv': (
        'string[] activate_controllers\n'
        'string[] deactivate_controllers\n'
        'int32 strictness\n'
        'int32 BEST_EFFORT=1\n'
        'int32 STRICT=2\n'
        'int32 AUTO=3\n'
        'int32 FORCE_AUTO=4\n'
        'bool activate_asap\n'
        'builtin_interfaces/Duration timeout\n'
        '---\n'
        'bool ok\n'
        'string message\n'),
}
#: the packages whose interfaces the definitions use (service_msgs: every Jazzy service's Event)
DEPENDENCIES = ('builtin_interfaces', 'service_msgs')
#: the libraries, in build order: name, C++?, generated sources, libraries linked (``~``: this
#: package's; ``*``: the same library of each dependency, as rosidl_generate_interfaces links)
LIBRARIES = (
    ('rosidl_generator_c', False, 'c',
     ['rosidl_runtime_c', 'rcutils', '*rosidl_generator_c']),
    ('rosidl_typesupport_fastrtps_c', True, 'fastrtps_c',
     ['~rosidl_generator_c', 'rosidl_runtime_c', 'rcutils', 'fastcdr', 'rmw',
      'rosidl_typesupport_fastrtps_c', 'rosidl_typesupport_fastrtps_cpp',
      '*rosidl_typesupport_fastrtps_c', '*rosidl_generator_c']),
    ('rosidl_typesupport_c', True, 'typesupport_c',
     ['~rosidl_generator_c', 'rosidl_typesupport_c', 'rosidl_runtime_c', 'rcutils', 'rcpputils',
      '*rosidl_typesupport_c']),
    ('rosidl_generator_py', False, 'py',
     ['~rosidl_generator_c', '~rosidl_typesupport_c', 'rosidl_runtime_c', 'rcutils',
      '*rosidl_generator_py', '*rosidl_generator_c']),
)
#: the Python extension that ``rosidl_generator_py.import_type_support`` imports
EXTENSION_LIBRARIES = ['~rosidl_generator_py', '~rosidl_generator_c', '~rosidl_typesupport_c',
                       'rosidl_runtime_c', 'rcutils', 'rmw', 'rosidl_typesupport_c']


def _libraries(names) -> list:
    """Return the linker's ``-l`` flags for ``names`` as :data:`LIBRARIES` writes them."""
    out = []
    for name in names:
        if name.startswith('~'):
            out.append(f'{PACKAGE}__{name[1:]}')
        elif name.startswith('*'):
            out += [f'{d}__{name[1:]}' for d in DEPENDENCIES]
        else:
            out.append(name)
    return [f'-l{x}' for x in out]


def cache_dir() -> Path:
    """Return the build's directory: under $TMPDIR, named by a hash of the definitions."""
    digest = hashlib.sha256(repr((sorted(DEFINITIONS.items()), LIBRARIES, sys.prefix,
                                  sys.version)).encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / f'pg_node_{PACKAGE}_{digest}'


def _generate(root: Path) -> dict:
    """Write the definitions, translate them to IDL and run the generators; return sources."""
    with contextlib.redirect_stdout(io.StringIO()):     # the translator names each file
        return _generate_quietly(root)


def _generate_quietly(root: Path) -> dict:
    from rosidl_cli.command.translate.api import translate
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    src = root / 'src'
    for rel, text in DEFINITIONS.items():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        (src / rel).write_text(text)
    share = Path(sys.prefix) / 'share'
    includes = [str(share / d) for d in DEPENDENCIES]
    idl = translate(package_name=PACKAGE, interface_files=[f'{src}:{rel}' for rel in DEFINITIONS],
                    include_paths=includes, output_format='idl', output_path=root / 'idl')
    headers = root / 'include' / PACKAGE
    out = {
        'c': GenerateC('c').generate(PACKAGE, idl, includes, headers),
        'fastrtps_c': GenerateFastRTPSCTypesupport('fastrtps_c').generate(
            PACKAGE, idl, includes, headers),
        'typesupport_c': GenerateCTypesupport('c').generate(
            PACKAGE, idl, includes, root / 'typesupport_c'),
        'py': GeneratePython('py', typesupport_implementations=['rosidl_typesupport_c']).generate(
            PACKAGE, idl, includes, root / 'python' / PACKAGE),
    }
    return {k: [str(f) for f in v] for k, v in out.items()}


def _compile(root: Path, sources: dict) -> None:
    """Compile the generated sources into the libraries and the Python extension."""
    import numpy
    prefix = Path(sys.prefix)
    flags = ['-shared', '-fPIC', '-O1', '-w', f'-I{root / "include"}', f'-I{prefix / "include"}',
             *[f'-I{d}' for d in sorted(glob.glob(str(prefix / 'include' / '*')))],
             f'-I{sysconfig.get_paths()["include"]}', f'-I{numpy.get_include()}',
             f'-L{root / "lib"}', f'-L{prefix / "lib"}']
    (root / 'lib').mkdir(exist_ok=True)
    for name, cxx, kind, libs in LIBRARIES:
        soname = f'lib{PACKAGE}__{name}.so'
        ends = ('_s.c' if kind == 'py' else '.c', '.cpp')
        files = [f for f in sources[kind] if f.endswith(ends)]
        subprocess.run(['g++' if cxx else 'gcc', *flags, *files, '-o', str(root / 'lib' / soname),
                        f'-Wl,-soname,{soname}', f'-Wl,-rpath,$ORIGIN:{prefix / "lib"}',
                        *_libraries(libs)], check=True, capture_output=True)
    entry = [f for f in sources['py'] if f.endswith('.ep.rosidl_typesupport_c.c')]
    suffix = sysconfig.get_config_var('EXT_SUFFIX')
    target = root / 'python' / PACKAGE / f'{PACKAGE}_s__rosidl_typesupport_c{suffix}'
    subprocess.run(['gcc', *flags, *entry, '-o', str(target),
                    f'-Wl,-rpath,$ORIGIN/../../lib:{prefix / "lib"}',
                    *_libraries(EXTENSION_LIBRARIES)], check=True, capture_output=True)


def build() -> Path:
    """Build the types once into :func:`cache_dir` (a lock for parallel workers); return it."""
    root = cache_dir()
    root.parent.mkdir(parents=True, exist_ok=True)
    with open(str(root) + '.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / 'done').exists():
            # built aside and renamed: a build cut short leaves no half directory behind
            tmp = Path(tempfile.mkdtemp(prefix=root.name + '.', dir=root.parent))
            _compile(tmp, _generate(tmp))
            (tmp / 'done').write_text('')
            if root.exists():
                shutil.rmtree(root)
            tmp.rename(root)
    return root


def install() -> Path:
    """
    Build (or find) the types and make them importable in this process.

    rosidl_typesupport_c loads ``lib<package>__rosidl_typesupport_fastrtps_c.so`` by name at the
    first use (dlopen), which finds a library this process has loaded already by its soname;
    ``LD_LIBRARY_PATH`` is read at process start only, so the library is loaded here first.
    """
    root = build()
    lib = root / 'lib'
    for name, _, _, _ in LIBRARIES:
        ctypes.CDLL(str(lib / f'lib{PACKAGE}__{name}.so'), mode=ctypes.RTLD_GLOBAL)
    path = str(root / 'python')
    if path not in sys.path:
        sys.path.insert(0, path)
    os.environ['LD_LIBRARY_PATH'] = os.pathsep.join(
        [str(lib)] + [p for p in os.environ.get('LD_LIBRARY_PATH', '').split(os.pathsep) if p])
    return root
