"""Our threads carry their names to the OS (per-thread CPU in node-bench, top -H): the name the
kernel reports for a thread is the one it was given, shortened as Linux keeps it."""

import sys
import threading
from pathlib import Path

import pytest

from tissue_sim_ros.system.thread_names import name_os_thread, os_thread_name


def test_names_are_shortened_to_what_linux_keeps():
    assert os_thread_name('tissue_sim-engine') == 'ts-engine'
    assert os_thread_name('mcap-writer:tissue_sim_2026-11-27T13-57-40Z.mcap') == 'mcap-writer:tis'
    assert len(os_thread_name('tissue_sim-prediction-intake').encode()) == 15
    assert os_thread_name('ä' * 10) == 'ä' * 7          # never half a character


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='prctl and /proc are Linux')
def test_a_thread_is_seen_by_the_os_under_its_python_name():
    seen = {}

    def run():
        name_os_thread()
        seen['comm'] = Path(f'/proc/self/task/{threading.get_native_id()}/comm').read_text().strip()

    thread = threading.Thread(target=run, name='tissue_sim-engine')
    thread.start()
    thread.join()
    assert seen['comm'] == 'ts-engine'
    assert Path(f'/proc/self/task/{threading.get_native_id()}/comm').read_text().strip() != 'ts-engine'
