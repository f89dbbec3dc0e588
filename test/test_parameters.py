# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""One definition per setting: core fields -> node parameters, the YAML and toc-solve --help."""

from dataclasses import dataclass
import subprocess
import sys

from node_harness import CONFIG, NodeProcess, RosClient
import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters
from rclpy.parameter import parameter_value_to_python
from toc_ros import config, solve
from toc_ros.arm_config import ArmSettings
from toc_ros.core import PaperOptions, Problem, RobotParams, SolverOptions
from toc_ros.core.settings import from_parameters, parameter_table, setting
from toc_ros.nodes import parameters
from toc_ros.nodes.plant_node import PARAMETER_NAMES as PLANT_NAMES

ROS_TYPES = {
    'bool': ParameterType.PARAMETER_BOOL, 'integer': ParameterType.PARAMETER_INTEGER,
    'double': ParameterType.PARAMETER_DOUBLE, 'string': ParameterType.PARAMETER_STRING,
    'double_array': ParameterType.PARAMETER_DOUBLE_ARRAY,
    'string_array': ParameterType.PARAMETER_STRING_ARRAY}


def test_yaml_is_the_generated_table():
    assert CONFIG.read_text() == config.scenario_yaml(), (
        'config/toc_ros.yaml is out of date: python -m toc_ros.config --write')
    assert config.main(['--check']) == 0


def test_yaml_defaults_and_core_defaults_agree():
    assert config.load_parameters(str(CONFIG)) == config.DEFAULTS
    assert set(config.DEFAULTS) == {p.name for p in config.SCENARIO_TABLE}
    # The flat defaults build exactly the core's default objects ...
    assert config.problem_from_parameters(config.DEFAULTS) == Problem.paper()
    # ... except the wall-clock limit, which the nodes and the file set (the core's is none).
    assert config.options_from_parameters(config.DEFAULTS) == SolverOptions(timeout=60.0)
    assert config.robot_from_parameters(config.DEFAULTS) == RobotParams()
    # The historical names are kept.
    for name in ('solver.paper.K_B', 'solver.paper.J_eps', 'robot.u_max', 'obstacles.radius',
                 'solver.N', 'initial_state', 'goal_state', 'obstacles.margin'):
        assert name in config.DEFAULTS
    assert config.DEFAULTS['robot.u_max'] == [600.0, 500.0]
    assert config.DEFAULTS['solver.max_iterations'] == 0


def test_every_core_setting_is_a_parameter():
    """Every field with a setting() in the core dataclasses shows up in the table."""
    table = {p.name for p in config.SCENARIO_TABLE}
    for cls, prefix, count in ((RobotParams, 'robot.', 6), (PaperOptions, 'solver.paper.', 8)):
        names = {p.name for p in parameter_table(cls, prefix)}
        assert len(names) == count and names <= table
    for spec in config.SCENARIO_TABLE:
        assert spec.description and spec.ros_type in ROS_TYPES


def test_a_new_option_is_one_line():
    @dataclass(frozen=True)
    class Extended(SolverOptions):
        restarts: int = setting(2, 'number of restarts', low=0, high=9)

    table = {p.name: p for p in parameter_table(Extended, 'solver.')}
    spec = table['solver.restarts']
    assert (spec.default, spec.ros_type, spec.low, spec.high) == (2, 'integer', 0, 9)
    flat = {**config.DEFAULTS, 'solver.restarts': 5, 'solver.paper.K_B': 7.0}
    built = from_parameters(Extended, flat, 'solver.')
    assert built.restarts == 5 and built.paper.k_b == 7.0
    with pytest.raises(ValueError, match='integer'):
        from_parameters(Extended, {**flat, 'solver.restarts': 2.5}, 'solver.')


def test_bad_flat_values_are_clear_errors():
    with pytest.raises(config.ProblemError, match='robot.u_max must have 2 entries'):
        config.robot_from_parameters({**config.DEFAULTS, 'robot.u_max': [1.0, 2.0, 3.0]})
    with pytest.raises(config.ProblemError, match='equal lengths'):
        config.obstacle_rows({**config.DEFAULTS, 'obstacles.x': [1.0, 2.0]})
    with pytest.raises(config.ProblemError, match='integer'):
        config.problem_from_parameters({**config.DEFAULTS, 'solver.N': 'many'})


@pytest.mark.slow
def test_toc_solve_help_of_the_process_comes_from_the_table():
    """The same help as below, printed by python -m toc_ros.solve (a process: the full run)."""
    text = subprocess.run([sys.executable, '-m', 'toc_ros.solve', '--help'], check=True,
                          capture_output=True, text=True).stdout
    for spec in config.SCENARIO_TABLE:
        assert f'--{spec.name}' in text


def test_toc_solve_help_and_overrides_come_from_the_table(capsys):
    with pytest.raises(SystemExit) as done:
        solve._parse(['--help'])
    assert done.value.code == 0
    text = capsys.readouterr().out
    for spec in config.SCENARIO_TABLE:
        assert f'--{spec.name}' in text
    args = solve._parse(['--solver.paper.K_B', '700', '--robot.u_max', '650', '450',
                         '--solver.mode', 'paper', '--N', '200'])
    problem, options = solve.build_problem(args)
    assert options.paper.k_b == 700.0 and options.mode == 'paper'
    assert (problem.model.params.u1_max, problem.model.params.u2_max) == (650.0, 450.0)
    assert problem.n_intervals == 200


def test_node_parameter_names_are_in_the_table():
    assert set(PLANT_NAMES) <= set(parameters.TABLE)
    robot = {p.name for p in parameter_table(RobotParams, 'robot.')}
    assert robot <= set(PLANT_NAMES) and robot <= set(parameters.SOLVER_NODE_NAMES)
    assert set(parameters.SOLVER_NODE_NAMES) == set(config.DEFAULTS) | {
        p.name for p in parameter_table(parameters.SolverNodeSettings)} | {
        p.name for p in parameter_table(ArmSettings)}


@pytest.mark.slow
def test_declared_parameters_agree_with_the_table(tmp_path):
    """solver_node started without a parameter file declares the table's defaults and ranges."""
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, tmp_path, params_file=None)
    try:
        node.wait_for_log('ready:', timeout=180.0)
        names = parameters.SOLVER_NODE_NAMES
        get = client.node.create_client(GetParameters, client.name('solver_node/get_parameters'))
        describe = client.node.create_client(
            DescribeParameters, client.name('solver_node/describe_parameters'))
        got = client.call(get, GetParameters.Request(names=names)).values
        described = client.call(describe, DescribeParameters.Request(names=names)).descriptors
        for name, value, desc in zip(names, got, described):
            spec = parameters.TABLE[name]
            assert value.type == ROS_TYPES[spec.ros_type], name
            python = parameter_value_to_python(value)
            assert (list(python) if spec.ros_type.endswith('_array') else python) == spec.default
            assert desc.description == spec.full_description(), name
            if spec.low is not None and spec.ros_type == 'double':
                rng = desc.floating_point_range[0]
                assert (rng.from_value, rng.to_value) == (spec.low, spec.high), name
            if spec.low is not None and spec.ros_type == 'integer':
                rng = desc.integer_range[0]
                assert (rng.from_value, rng.to_value) == (spec.low, spec.high), name
            if spec.choices:
                assert all(c in desc.additional_constraints for c in spec.choices), name
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()


def test_solver_node_settings_are_built_once_as_typed_objects():
    """The node's typed settings carry exactly the flat values (no name looked up twice)."""
    from toc_ros.nodes.solver_settings import parameter_errors, SolverNodeConfig
    flat = {name: parameters.default(name) for name in parameters.SOLVER_NODE_NAMES}
    assert parameter_errors(flat) == []
    typed = SolverNodeConfig.from_flat(flat)
    for p in parameter_table(parameters.SolverNodeSettings):
        field_name = next(f for f in parameters.SolverNodeSettings.__dataclass_fields__.values()
                          if (f.metadata['toc_ros.setting'].ros_name or f.name) == p.name).name
        value = getattr(typed.node, field_name)
        assert (list(value) if isinstance(value, tuple) else value) == p.default, p.name
    assert list(typed.frames.joint_names) == flat['joint_names']
    assert typed.frames.base_frame == flat['base_frame']
    assert typed.robot.name == flat['robot.model'] and typed.options.mode == 'fast'
    assert typed.problem.obstacles == ((1.0, 1.0, 0.2),) and typed.problem.margin == 0.01
    assert list(typed.problem.x0) == flat['initial_state']
    assert typed.replanning and typed.model.nx == 4
    assert typed.model_keys() == {'robot_model': 'cylindrical', 'model_parameters': ''}
    changed = SolverNodeConfig.from_flat(dict(flat, **{
        'replan.rate': 0.0, 'replan.estimate': ['hand_mass'], 'obstacles.margin': 0.05}))
    assert changed.node.replan_rate == 0.0 and not changed.replanning
    assert changed.node.replan_estimate == ('hand_mass',) and changed.problem.margin == 0.05
    assert 'obstacles.margin' in changed.planning_data()
    assert 'obstacles.max_count' not in changed.planning_data()
    assert parameter_errors(dict(flat, **{'replan.estimate': ['no_such']}))
    assert parameter_errors(dict(flat, base_frame='/')) == ['base_frame must not be empty']


def test_arm_settings_refuse_more_intervals_than_arms_take_and_track_their_joints():
    # solver.N's declared range is every model's; arms are planned on at most 100000
    # intervals: refused when set, not at every goal. joint_names pick an arm's model, so they
    # are planning data (a change stops the plan of the old joints).
    from toc_ros.nodes.solver_settings import parameter_errors, planning_data
    flat = {name: parameters.default(name) for name in parameters.SOLVER_NODE_NAMES}
    flat.update({'robot.model': 'panda', 'joint_names': [f'panda_joint{i}' for i in range(1, 8)],
                 'initial_state': [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]})
    assert parameter_errors(flat) == []
    assert any('exceeds the 100000 intervals' in e
               for e in parameter_errors(dict(flat, **{'solver.N': 200000})))
    assert planning_data(flat)['joint_names'] == tuple(flat['joint_names'])
    assert 'joint_names' not in planning_data(dict(flat, **{'robot.model': 'cylindrical'}))
