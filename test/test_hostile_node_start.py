"""The node refuses bad ROS arguments and parameter files with one line and exit code 1."""


from conftest import REPO
import pytest
from rosnode import assert_refused_in_one_line, start_refusals

pytestmark = pytest.mark.slow
TIMEOUT = 60.0

BROKEN_YAML = 'polyline_mapper_node:\n  ros__parameters:\n    foo: [1, 2\n'
NOT_ROS_LAYOUT = 'foo: 1\n'
EMPTY_FRAME = 'polyline_mapper_node:\n  ros__parameters:\n    fixed_frame: ""\n'
EMPTY_FRAME_ANY = '/**:\n  ros__parameters:\n    fixed_frame: ""\n'    # as the shipped files

# argv after --ros-args ('{dir}' is a scratch folder) -> what the one line must say.
CASES = [
    (['--params-file', '{dir}/missing.yaml'], ['params file', 'missing.yaml: no such file']),
    (['--params-file', '{dir}/broken.yaml'], ['broken.yaml: not valid YAML', 'line 4']),
    (['--params-file', '{dir}/binary.yaml'], ['binary.yaml: binary data']),
    (['--params-file', '{dir}'], ['is a directory']),
    (['--params-file', '{dir}/layout.yaml'],
     ['layout.yaml: Cannot have a value before ros__parameters']),
    (['--params-file', '{dir}/empty_frame.yaml'],
     ['fixed_frame must not be empty: it must be a frame name']),
    # A file keyed /** reaches the node under a namespace too (one keyed by the node's name is
    # ignored there): its empty fixed_frame is read, and refused.
    (['-r', '__ns:=/robot1', '--params-file', '{dir}/empty_frame_any.yaml'],
     ['fixed_frame must not be empty: it must be a frame name']),
    (['-p', 'pose_source:='], ['pose_source must be one of tf, odom, scan, got an empty value']),
    (['-p', 'fixed_frame:='], ['fixed_frame must be a frame name']),
    (['-p', 'smemsf.init:='], ['smemsf.init must be one of diagonals, single, random']),
    (['-p', 'map_output_path:='], ['map_output_path must not be empty']),
    (['-p', 'laser_x:='], ['laser_x:=: no value', 'float']),
    # A double written without a point is an integer to ROS 2: rclpy's refusal, with the remedy.
    (['-p', 'map_publish_period:=0'],
     ["'map_publish_period'", "expecting type 'DOUBLE'", 'write 0.0, not 0']),
    (['-p', 'initial_pose:=[1, 2, 0]'], ["expecting type 'DOUBLE_ARRAY'", 'write 0.0, not 0']),
    # Declared by rclpy itself, before the node's own parameters: a traceback (node audit).
    (['-p', 'use_sim_time:=maybe'], ["'use_sim_time'", "expecting type 'BOOL'"]),
    (['-p', 'use_sim_time:=1'], ["'use_sim_time'", "expecting type 'BOOL'"]),
    (['-p'], ['trailing -p flag']),
    (['--bogus'], ['unknown ROS argument(s): --bogus']),
    (['--log-level', 'nonsense'], ['log level']),
    # The inputs' QoS overrides (rclpy's own errors were tracebacks, a depth of 0 or less an
    # "invalid allocator" from rcl).
    (['-p', 'qos_overrides./scan.subscription.reliability:=bogus'],
     ['qos_overrides./scan.subscription: ', 'reliability', 'bogus']),
    (['-p', 'qos_overrides./scan.subscription.depth:=0'],
     ['qos_overrides./scan.subscription: ', 'depth must be >= 1 with history keep_last, got 0']),
    (['-p', 'pose_source:=odom', '-p', 'qos_overrides./odom.subscription.depth:=abc'],
     ['qos_overrides./odom.subscription: ', "expecting type 'INTEGER'"]),
]


@pytest.fixture(scope='module')
def outcomes(tmp_path_factory):
    """Start the node once per case (four at a time); return (argv, rc, output) per case."""
    folder = tmp_path_factory.mktemp('start')
    (folder / 'broken.yaml').write_text(BROKEN_YAML)
    (folder / 'binary.yaml').write_bytes(bytes(range(256)) * 4)
    (folder / 'layout.yaml').write_text(NOT_ROS_LAYOUT)
    (folder / 'empty_frame.yaml').write_text(EMPTY_FRAME)
    (folder / 'empty_frame_any.yaml').write_text(EMPTY_FRAME_ANY)
    argvs = [[a.format(dir=folder) for a in argv] for argv, _ in CASES]
    return start_refusals(argvs, TIMEOUT)


@pytest.mark.parametrize('case', range(len(CASES)), ids=[' '.join(a) for a, _ in CASES])
def test_bad_start_arguments_exit_1_with_one_line(outcomes, case):
    assert_refused_in_one_line(outcomes[case], CASES[case][1])


def test_the_shipped_parameter_file_passes_the_start_checks():
    from polyline_mapper.ros.startup import check_ros_args, StartupError
    shipped = sorted((REPO / 'config').glob('*.yaml'))
    assert shipped
    check_ros_args(['node', '--ros-args'] + [a for p in shipped for a in ('--params-file', str(p))]
                   + ['-p', 'fixed_frame:=odom', '-p', 'polyline_mapper_node:pose_source:=odom'])
    with pytest.raises(StartupError, match='pose_source must be one of'):
        check_ros_args(['node', '--ros-args', '-p', 'polyline_mapper_node:pose_source:='])
    # Arguments outside --ros-args ... -- are not ROS arguments.
    check_ros_args(['node', '-p', 'pose_source:=', '--ros-args', '--', '-p', 'pose_source:='])


def test_parameters_the_node_does_not_have_are_named_with_a_hint():
    # rcl keeps a -p or params-file value for an undeclared name without a word: fit's short
    # 'sigma' (the node's smemsf.sigma) or a misspelt 'scan_matchng' was silently not used
    # (new-user audit). The node warns, naming them (test_node_modes starts one).
    import yaml
    from polyline_mapper.config import _ros_parameters
    from polyline_mapper.params import unknown_params
    assert unknown_params(['sigma', 'scan_matchng', 'smemsf.sigmaa', 'nosuch', 'scan_matching',
                           'use_sim_time', 'qos_overrides./scan.subscription.depth']) == [
        'nosuch', 'scan_matchng (did you mean scan_matching?)',
        'sigma (did you mean smemsf.sigma?)', 'smemsf.sigmaa (did you mean smemsf.sigma?)']

    def names(tree, prefix=''):
        for key, value in tree.items():
            if isinstance(value, dict):
                yield from names(value, f'{prefix}{key}.')
            else:
                yield prefix + key
    for path in sorted((REPO / 'config').glob('*.yaml')):     # the shipped files: all known
        params = list(names(_ros_parameters(yaml.safe_load(path.read_text()), str(path))))
        assert params and unknown_params(params) == [], path
