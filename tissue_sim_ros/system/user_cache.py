"""The per-user cache directory of the package: $XDG_CACHE_HOME/tissue_sim_ros/<name>, else
~/.cache/tissue_sim_ros/<name>. One known place for what is worth keeping between runs (numba's
compiled kernels, the degradation ladder's measured errors per scene) instead of the installed
package's directory, which may be read-only on a ROS install. Standard library only: it is read
before numba is first imported."""
import os

__all__ = ['user_cache_dir', 'sources_key', 'scene_cache_entry', 'write_whole']


def user_cache_dir(name: str) -> str | None:
    """The directory for ``name`` (not created here); None without an absolute home."""
    base = os.environ.get('XDG_CACHE_HOME', '')
    if not os.path.isabs(base):
        base = os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'tissue_sim_ros', name) if os.path.isabs(base) else None


def sources_key(directory: str) -> str:
    """'engine-' and the first 16 hex digits of the sha256 of the .py files under ``directory``
    (their paths relative to it and contents, in path order): changes when any of them does."""
    import hashlib
    digest = hashlib.sha256()
    names = sorted(os.path.relpath(os.path.join(folder, name), directory)
                   for folder, _, files in os.walk(directory) for name in files if name.endswith('.py'))
    for name in names:
        with open(os.path.join(directory, name), 'rb') as source:
            digest.update(name.encode() + b'\0' + source.read() + b'\0')
    return 'engine-' + digest.hexdigest()[:16]


def scene_cache_entry(name: str, text: str):
    """(directory, key) of the cache entry for a scene: the directory for ``name`` (a temporary
    one without a home; not created here) and the first 20 hex digits of the sha256 of the
    scene's complete text (``scene_yaml``, mesh files absolute: the key is where it points)."""
    import hashlib
    import tempfile
    where = user_cache_dir(name) or os.path.join(tempfile.gettempdir(), f'tissue_sim_ros_{name}')
    return where, hashlib.sha256(text.encode()).hexdigest()[:20]


def write_whole(path, text: str) -> None:
    """Write ``text`` to ``path`` (a pathlib.Path) whole or not at all: a cache entry another run
    may read while this one is interrupted is never half written."""
    partial = path.with_suffix('.partial')
    partial.write_text(text)
    partial.replace(path)
