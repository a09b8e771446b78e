"""MkDocs hook: lets mkdocstrings read the ``stillpoint`` package from source.

The repository keeps ``engine/``, ``drivers/`` and ``tools/`` at its top and installs them as
subpackages of ``stillpoint`` (pyproject's package-dir), a mapping a static reader of the source
cannot follow. At build time this hook lays out the package as it is installed, in a temporary
folder of symbolic links (``stillpoint/__init__.py`` from ``_stillpoint/``, ``stillpoint/engine``
-> ``engine/``, ...), read from pyproject's ``[tool.setuptools.package-dir]``, and points the
Python handler there. Nothing is imported and nothing is written into the repository."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

from mkdocs.plugins import event_priority

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib


def package_tree(repo: Path, dest: Path) -> Path:
    """Symbolic links under ``dest`` giving the installed package layout; returns ``dest``."""
    mapping = tomllib.loads((repo / "pyproject.toml").read_text(encoding="utf-8"))
    dirs = mapping["tool"]["setuptools"]["package-dir"]
    for name, src in sorted(dirs.items(), key=lambda kv: kv[0].count(".")):
        parts = name.split(".")
        target = dest.joinpath(*parts)
        if len(parts) == 1:  # the root package: a folder of links to its own files
            target.mkdir(parents=True)
            for f in (repo / src).iterdir():
                if f.suffix == ".py":
                    (target / f.name).symlink_to(f.resolve())
        else:
            target.symlink_to((repo / src).resolve(), target_is_directory=True)
    return dest


@event_priority(100)  # before mkdocstrings' own on_config, which creates the handler
def on_config(config):
    repo = Path(config.config_file_path).resolve().parent
    tmp = Path(tempfile.mkdtemp(prefix="stillpoint-api-"))
    atexit.register(shutil.rmtree, tmp, True)
    package_tree(repo, tmp)
    handlers = config.plugins["mkdocstrings"].config.setdefault("handlers", {})
    handlers.setdefault("python", {})["paths"] = [str(tmp)]
    return config
