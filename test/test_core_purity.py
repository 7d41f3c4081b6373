"""core/ stays ROS-free: no rclpy, rosidl or message-package import anywhere in it."""

import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[1] / 'ament_formation' / 'core'
FORBIDDEN_PREFIXES = ('rclpy', 'rosidl', 'rmw', 'launch', 'builtin_interfaces')


def _imported_modules(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module


def _is_forbidden(module: str) -> bool:
    top = module.split('.')[0]
    return (
        top.startswith(FORBIDDEN_PREFIXES) or top.endswith('_msgs') or top.endswith('_interfaces')
    )


def test_core_has_modules():
    assert len(list(CORE.glob('*.py'))) >= 2


def test_core_imports_no_ros():
    offenders = {
        f'{path.name}: {module}'
        for path in CORE.rglob('*.py')
        for module in _imported_modules(path)
        if _is_forbidden(module)
    }
    assert not offenders, f'ROS imports in core/: {sorted(offenders)}'


def test_purity_check_detects_ros_imports(tmp_path):
    probe = tmp_path / 'probe.py'
    probe.write_text('import rclpy\nfrom sensor_msgs.msg import Image\nimport numpy\n')
    found = [m for m in _imported_modules(probe) if _is_forbidden(m)]
    assert found == ['rclpy', 'sensor_msgs.msg']
