"""The machine the package runs on: threads, processes, caches and its own files.

Standard library only (numba_threads configures numba before its first import).

- :mod:`.paths`: the package's source directory and shared files (config/, data/);
- :mod:`.user_cache`: the per-user cache directory (compiled kernels, per-scene results);
- :mod:`.numba_threads`: numba's threading layer, spin policy, vector width and cache place;
- :mod:`.thread_names`: our threads' names where the operating system shows them;
- :mod:`.process_pools`: stopping a process pool now;
- :mod:`.child_env`: a child process's environment to import a given source tree.
"""
__all__ = ['child_env', 'numba_threads', 'paths', 'process_pools', 'thread_names', 'user_cache']
