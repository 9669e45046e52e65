"""The docs point at files that exist: a path a reader is told to open is in the repository."""
from __future__ import annotations

import importlib.util
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted([ROOT / 'README.md', *(ROOT / 'docs').rglob('*.md')])
# A repository path as the docs write it: folders and a file with an extension of the source tree. Paths in a run
# folder (runs/..., logs/..., bag/...) or on the reader's machine are what a run writes, not files of ours.
PATH = re.compile(r'(?<![\w./~-])((?:[\w-]+/)+[\w-]+\.(?:py|md|yaml|sh|msg|xml|cfg))(?![\w/])')
WRITTEN = ('runs/', 'logs/', 'bag/', 'report/', 'tmp/', 'run/', 'out/')
NEW = 'a new file:'  # a worked example names the file a contributor would add


def tracked() -> list[str]:
    return subprocess.run(['git', 'ls-files'], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()


@pytest.mark.parametrize('doc', DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_file_a_doc_names_exists(doc: Path) -> None:
    files = tracked()
    text = '\n'.join(line for line in doc.read_text().splitlines() if NEW not in line)
    missing = sorted({m for m in PATH.findall(text)
                      if not m.startswith(WRITTEN)
                      and not any(f == m or f.endswith('/' + m) for f in files)
                      and not (doc.parent / m).exists()})
    assert not missing, f'{doc.relative_to(ROOT)} names files that do not exist: {missing}'


def test_every_key_of_a_run_folder_is_in_the_docs(tmp_path: Path) -> None:
    """docs/design.md, "A run's records", names every column and key a run folder's files hold."""
    import json

    import numpy as np
    from world_sim.core import records
    from world_sim.core.hearing import LINK_COLUMNS
    from world_sim.core.physics import Users
    users = Users(np.zeros((2, 3)), np.zeros(2, dtype=np.intp), np.zeros((1, 2)), np.ones(1))
    motion = records.Motion(np.zeros(1), np.zeros((1, 2, 2)), np.ones((1, 2), bool), np.zeros((1, 2)))
    records.write_users(tmp_path / records.USERS_FILE, users, motion)
    records.write_failures(tmp_path / records.FAILURES_FILE, np.array([1]), 3, [(3, [1], 'scheduled')])
    with np.load(tmp_path / records.USERS_FILE) as f:
        keys = set(f.files)
    doc = json.loads((tmp_path / records.FAILURES_FILE).read_text())
    keys |= set(doc) | set(doc['events'][0])
    keys |= {*records.METRICS_COLUMNS, *records.TRAJECTORY_COLUMNS, *records.ESTIMATE_COLUMNS,
             *records.VEHICLE_COLUMNS}
    text = (ROOT / 'docs' / 'design.md').read_text()
    section = text.split("## A run's records", 1)[1].split('\n## ', 1)[0]
    missing = sorted(keys - set(re.findall(r'`(\w+)`', section)))
    assert 'hearing.LINK_COLUMNS' in section and LINK_COLUMNS, 'the channel columns are named by their constant'
    assert not missing, f"docs/design.md, \"A run's records\", does not name: {missing}"


def test_the_glossary_names_every_rule() -> None:
    """docs/design.md's glossary lists every rule a study can switch off, by the name `without:` takes."""
    from uav_agent.core.ablation import RULES
    text = (ROOT / 'docs' / 'design.md').read_text()
    glossary = text.split('## Glossary', 1)[1].split('\n## ', 1)[0]
    named = set(re.findall(r'^\| `(\w+)` \|', glossary, flags=re.M))
    assert not set(RULES) - named, f'rules missing from the glossary: {sorted(set(RULES) - named)}'


def test_the_source_keeps_the_house_limits() -> None:
    """tools/code_shape.py: no function over 60 lines, no module over 400 (cli.py 120, the launcher under 300)."""
    spec = importlib.util.spec_from_file_location('code_shape', ROOT / 'tools' / 'code_shape.py')
    assert spec is not None and spec.loader is not None
    shape = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(shape)
    assert not shape.over_limits(ROOT / 'src'), shape.over_limits(ROOT / 'src')
