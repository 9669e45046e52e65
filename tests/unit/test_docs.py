"""The docs point at files that exist: a path a reader is told to open is in the repository."""
from __future__ import annotations

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
