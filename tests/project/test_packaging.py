"""The installed layout: every package directory is listed in pyproject.toml, the CLI starts."""

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOP = {"engine": "stillpoint.engine", "drivers": "stillpoint.drivers", "tools": "stillpoint.tools"}
# developers' scripts kept out of the wheel (they stay in the repository, under tools/)
NOT_SHIPPED = {"stillpoint.tools.benchmarks", "stillpoint.tools.crosschecks"}


def test_every_package_dir_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = set()
    for top, dotted in TOP.items():
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top)
            name = ".".join([dotted, *rel.parts]) if rel.parts else dotted
            if not any(name == d or name.startswith(d + ".") for d in NOT_SHIPPED):
                found.add(name)
    assert found - listed == set(), f"add these packages to pyproject.toml: {sorted(found - listed)}"
    shipped = {p for p in listed if any(p == d or p.startswith(d + ".") for d in NOT_SHIPPED)}
    assert not shipped, f"benchmarks and cross-checks are not shipped: remove {sorted(shipped)}"


def test_the_package_says_it_is_typed():
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert (ROOT / "_stillpoint" / "py.typed").is_file()
    assert "py.typed" in conf["package-data"]["stillpoint"]


def test_cli_help_lists_commands():
    out = subprocess.run([sys.executable, "-m", "stillpoint.tools", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "COMMAND" in out


def test_running_one_command_imports_only_that_command_module():
    code = ("import sys; from stillpoint.tools import cli; cli.build_parser(cli._only_requested(['inspect','x']));"
            "print(sorted(m for m in sys.modules if m.startswith('stillpoint.tools.cli.commands.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "stillpoint.tools.cli.commands.inspect" in out
    assert "stillpoint.tools.cli.commands.align" not in out


def test_unknown_command_is_a_usage_error():
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "no-such-command"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "invalid choice" in r.stderr


def test_version_in_api_and_cli():
    import stillpoint
    from importlib.metadata import version
    assert stillpoint.__version__ == version("stillpoint")
    out = subprocess.run([sys.executable, "-m", "stillpoint.tools", "--version"],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"stillpoint {stillpoint.__version__}"


def test_python_m_stillpoint_is_the_command():
    out = subprocess.run([sys.executable, "-m", "stillpoint", "--version"],
                         capture_output=True, text=True, check=True).stdout
    import stillpoint
    assert out.strip() == f"stillpoint {stillpoint.__version__}"


def test_cutpoint_registry_is_package_data():
    import tomllib
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "cutpoints.csv" in conf["package-data"]["stillpoint.engine.outcomes"]
    from stillpoint.engine.outcomes.cutpoints import REGISTRY, registry
    assert REGISTRY.is_file() and len(registry()) >= 13


def test_import_from_the_folder_holding_a_clone_named_stillpoint(tmp_path):
    """The README's layout: the clone (named ``stillpoint``) with ``shared/`` beside it, Python
    started in the folder that holds both. The clone is then found first on sys.path; it must
    be the package (``stillpoint.read``, the CLI), not an empty namespace package."""
    (tmp_path / "stillpoint").symlink_to(ROOT, target_is_directory=True)
    code = ("import stillpoint, stillpoint.engine.run as r; "
            "print(callable(stillpoint.read), callable(stillpoint.tables), r.RunSettings.__name__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True)
    assert out.returncode == 0 and out.stdout.split() == ["True", "True", "RunSettings"], out.stderr
    ver = subprocess.run([sys.executable, "-m", "stillpoint", "--version"], cwd=tmp_path,
                         capture_output=True, text=True)
    assert ver.returncode == 0 and ver.stdout.startswith("stillpoint "), ver.stderr
