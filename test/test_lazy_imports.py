"""What importing a part of the package loads: writing and reading a log, or the trials, imports no
numba (and no rclpy); the engine's names still load on first use, with the threading policy."""

import os
import subprocess
import sys
import textwrap

_NO_NUMBA = textwrap.dedent('''
    import os, sys
    import tissue_sim_ros
    from tissue_sim_ros.io import mcap as mcap_log
    from tissue_sim_ros.io.mcap import reader as mcap_reader
    from tissue_sim_ros.io.mcap import recovery as mcap_recovery
    from tissue_sim_ros.io.mcap import writer as mcap_writer
    from tissue_sim_ros.io.mcap import message_definitions as ros_message_definitions
    from tissue_sim_ros.io.mcap import rosbag2_qos
    path = sys.argv[1]
    with mcap_log.McapRecorder(path, metadata={'scene': 'x'}) as rec:
        rec.add_topic('t', 'std_msgs/msg/UInt8', {})
        for i in range(5):
            rec.write('t', bytes([0, 1, 0, 0, i]), 1000 + i)
    values = [m.message.data for m in mcap_log.read_log(path)]
    assert values == list(range(5)), values
    assert mcap_log.recover_truncated(path)['complete']
    assert mcap_log.read_metadata(path)['package_version'] == tissue_sim_ros.__version__
    loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')
                    or m.startswith('tissue_sim_ros.engine'))
    print('loaded:', loaded)
    ts = tissue_sim_ros  # then the engine names still load on first use, policy applied
    from tissue_sim_ros import SimulationDiverged
    import numba
    assert ts.Material(3000.0, 0.45, 1000.0).young_modulus == 3000.0
    assert issubclass(SimulationDiverged, Exception) and 'Simulation' in dir(ts)
    print('layer:', numba.config.THREADING_LAYER, os.environ.get('GOMP_SPINCOUNT'))
''')


def test_writing_and_reading_a_log_imports_no_numba(tmp_path):
    env = {k: v for k, v in os.environ.items()
           if k not in ('NUMBA_THREADING_LAYER', 'GOMP_SPINCOUNT', 'OMP_WAIT_POLICY')}
    r = subprocess.run([sys.executable, '-c', _NO_NUMBA, str(tmp_path / 'x.mcap')], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert 'loaded: []' in r.stdout, r.stdout
    assert 'layer: omp 10000' in r.stdout, r.stdout


def test_io_modules_import_no_numba_and_no_rclpy():
    code = ('import sys\n'
            'import tissue_sim_ros.io.trials.data_spec, tissue_sim_ros.io.trials.mcap_files\n'
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'rclpy')))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]'
