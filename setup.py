"""ament_python packaging for ament_formation (colcon build, or pip install -e . in the venv)."""

from glob import glob
import os

from setuptools import find_packages, setup

PACKAGE = 'ament_formation'
# scripts/ files installed to share/ament_formation/scripts (the rest are source-tree tools)
LAUNCH_SCRIPTS = [
    f'scripts/{name}'
    for name in (
        'launch_common.sh',
        'launch_sim.sh',
        'launch_base.sh',
        'launch_robot.sh',
        'launch_info.py',
        'ros_env.sh',
    )
]


def config_files(subdir):
    """data_files entries for every file under config/<subdir> (keeps the tree layout)."""
    entries = []
    root = os.path.join('config', subdir) if subdir else 'config'
    for dirpath, _dirs, files in os.walk(root):
        paths = [os.path.join(dirpath, f) for f in files]
        if paths:
            entries.append((os.path.join('share', PACKAGE, dirpath), paths))
    return entries


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml', 'LICENSE']),
        (f'share/{PACKAGE}/docs', glob('docs/*.md') + glob('docs/*.json')),
        # the launchers (`formation run` starts scripts/launch_sim.sh): from share/ament_formation
        # they start the installed programs (lib/ament_formation) with share's config/params
        (f'share/{PACKAGE}/scripts', LAUNCH_SCRIPTS),
    ]
    + config_files(''),
    install_requires=['setuptools'],
    # colcon test runs pytest only for a package that declares it as a test dependency
    extras_require={'test': ['pytest', 'pytest-timeout', 'hypothesis']},
    zip_safe=True,
    maintainer='ament_formation maintainers',
    maintainer_email='maintainers@ament-formation.invalid',
    description=(
        'Sliding-mode formation control with elliptical limit-cycle avoidance (ROS 2 Jazzy).'
    ),
    license='Apache-2.0',
    # every console script checks its libraries first (tools/entry.py, core/requirements.py)
    entry_points={
        'console_scripts': [
            'formation = ament_formation.tools.entry:formation',
            'formation_world = ament_formation.tools.entry:formation_world',
            'formation_tracker = ament_formation.tools.entry:formation_tracker',
            'formation_controller = ament_formation.tools.entry:formation_controller',
            'formation_bridge = ament_formation.tools.entry:formation_bridge',
            'formation_coordinator = ament_formation.tools.entry:formation_coordinator',
            'formation_team = ament_formation.tools.entry:formation_team',
            'formation_live_view = ament_formation.tools.entry:formation_live_view',
        ],
    },
)
