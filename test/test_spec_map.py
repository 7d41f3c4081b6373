"""Every spec label S2-S10 has ONE implementing function (core/spec_map.py), marked
``# implements: <label>`` in the package, and no other function is marked with it (issue 12).
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path
import re

from ament_formation.core.spec_map import SPEC_MAP

PKG = Path(__file__).resolve().parents[1] / 'ament_formation'
MARK = re.compile(r'^\s*# implements: (.+)$')


def markers(root: Path = PKG) -> dict[str, list[str]]:
    """Map label -> ['module:qualname', ...] of every marked function or class under ``root``."""
    found: dict[str, list[str]] = {}
    for path in sorted(root.rglob('*.py')):
        lines = path.read_text().split('\n')
        tree = ast.parse('\n'.join(lines))
        rel = path.relative_to(root).with_suffix('')
        module = '.'.join(rel.parts[1:]) if rel.parts[0] == 'core' else '../' + '.'.join(rel.parts)

        def visit(node, prefix):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                    first = min([d.lineno for d in child.decorator_list] + [child.lineno])
                    m = MARK.match(lines[first - 2]) if first >= 2 else None
                    name = prefix + child.name
                    if m:
                        for label in m.group(1).split(','):
                            found.setdefault(label.strip(), []).append(f'{module}:{name}')
                    visit(child, name + '.')

        visit(tree, '')
    return found


def test_every_label_s2_to_s10_is_mapped():
    tops = {re.match(r'S\d+', k).group(0) for k in SPEC_MAP}
    assert {f'S{k}' for k in range(2, 11)} <= tops


def test_each_mapped_function_exists():
    for label, target in SPEC_MAP.items():
        module, qual = target.split(':')
        obj = importlib.import_module(f'ament_formation.core.{module}')
        for part in qual.split('.'):
            obj = getattr(obj, part)
        assert callable(obj), label


def test_one_implementation_per_label():
    found = markers()
    assert sorted(found) == sorted(SPEC_MAP), 'labels marked in the package != SPEC_MAP'
    for label, where in found.items():
        assert where == [SPEC_MAP[label]], f'{label}: implemented by {where}'


def test_a_second_implementation_is_caught(tmp_path):
    pkg = tmp_path / 'ament_formation' / 'core' / 'control'
    pkg.mkdir(parents=True)
    (pkg / 'smc.py').write_text('# implements: S3\ndef smc_torque_k():\n    pass\n')
    (pkg / 'other.py').write_text(
        'class C:\n    # implements: S3, S5\n    @staticmethod\n    def law():\n        pass\n'
    )
    found = markers(tmp_path / 'ament_formation')
    assert found == {
        'S3': ['control.other:C.law', 'control.smc:smc_torque_k'],
        'S5': ['control.other:C.law'],
    }
