"""How the source measures against the house limits: functions of at most 60 lines, cli.py at most 120 lines,
the launcher under 300. Prints every place over a limit; exit 1 if there is one.

    python3 tools/code_shape.py [--root DIR]

Standard library only: it reads the files as text and parses them with `ast`, nothing is imported.
"""
from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

FUNCTION_LINES = 60
FILE_LINES = {'uav_flock_tools/uav_flock_tools/cli.py': 120, 'uav_flock_tools/uav_flock_tools/launcher.py': 299}


def long_functions(src: Path) -> list[tuple[int, str]]:
    """(lines, 'file:line name') of every function or method longer than FUNCTION_LINES, longest first."""
    found = []
    for path in sorted(src.rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                if lines > FUNCTION_LINES:
                    found.append((lines, f'{path.relative_to(src)}:{node.lineno} {node.name}'))
    return sorted(found, reverse=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--root', type=Path, default=Path(__file__).resolve().parents[1], help='the repository')
    src = parser.parse_args().root / 'src'
    over = [f'{lines} lines: {where} (limit {FUNCTION_LINES})' for lines, where in long_functions(src)]
    for name, limit in FILE_LINES.items():
        lines = len((src / name).read_text().splitlines())
        print(f'{name}: {lines} lines (limit {limit})')
        if lines > limit:
            over.append(f'{lines} lines: {name} (limit {limit})')
    print('\n'.join(over) if over else f'every function within {FUNCTION_LINES} lines')
    return 1 if over else 0


if __name__ == '__main__':
    sys.exit(main())
