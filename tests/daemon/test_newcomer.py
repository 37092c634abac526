"""What a newcomer meets on a fresh clone: the README's links resolve inside the repository, its example
outputs are ignored by git, and the viky camera config finds its producer wherever Python is."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import ConfigError

ROOT = Path(__file__).parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_docs_point_inside_the_repository(doc):
    text = doc.read_text()
    assert "../shared" not in text and "shared/seed" not in text
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)\s]*)?\)", text):  # markdown links, anchors too
        if not re.match(r"[a-z]+:", target):
            assert (doc.parent / target).exists(), f"{doc.name} links to {target}, which does not exist"


def test_sources_point_inside_the_repository():
    for path in sorted(ROOT.glob("*/**/*.py")) + sorted(ROOT.glob("config/**/*.toml")):
        in_a_venv = path.relative_to(ROOT).parts[0].startswith(".venv")  # .venv, .venv-newest
        if in_a_venv or "build" in path.parts or path.name == "test_newcomer.py":
            continue
        text = path.read_text()
        assert "../shared" not in text and "shared/DESIGN" not in text and "shared/seed" not in text, path


def test_readme_example_outputs_are_ignored_by_git():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    names = re.findall(r"^\.venv/bin/monoguide .*--out (\S+\.png)$", (ROOT / "README.md").read_text(), re.MULTILINE)
    assert set(names) >= {"fig5.png", "sim.png", "viky.png"}
    run = subprocess.run(["git", "check-ignore", *names], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert run.stdout.split() == names


def test_viky_config_finds_the_producer_of_the_installed_genicam_wheel():
    text = (ROOT / "config" / "viky-camera.toml").read_text()
    assert "python3" not in text and "site-packages" not in text
    cti = load_cell_config(ROOT / "config" / "viky-camera.toml").camera.cti
    import genicam

    assert cti == Path(genicam.__file__).parent / "viky.cti" and cti.is_file()


def test_a_relative_cti_path_is_still_relative_to_the_config(tmp_path):
    text = (ROOT / "config" / "viky-camera.toml").read_text().replace('"genicam:viky.cti"', '"producers/x.cti"')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    assert load_cell_config(path).camera.cti == tmp_path / "producers" / "x.cti"


def test_genicam_prefix_without_the_package_is_a_config_error(tmp_path, monkeypatch):
    import importlib.util

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "genicam" else
                        real_find_spec(name, *a))
    path = tmp_path / "cell.toml"
    path.write_text((ROOT / "config" / "viky-camera.toml").read_text())
    with pytest.raises(ConfigError, match="genicam package is not installed"):
        load_cell_config(path)
