"""How the source measures against the house limits: functions of at most 60 lines, modules of at most 400
(cli.py 120, the launcher under 300). Prints every place over a limit; exit 1 if there is one.

    python3 tools/code_shape.py [--root DIR]

Standard library only: it reads the files as text and parses them with `ast`, nothing is imported.
"""
from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

FUNCTION_LINES = 60
MODULE_LINES = 400
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


def long_modules(src: Path) -> list[tuple[int, str, int]]:
    """(lines, file, limit) of every module over its limit (FILE_LINES, else MODULE_LINES), longest first."""
    found = []
    for path in sorted(src.rglob('*.py')):
        name = str(path.relative_to(src))
        lines, limit = len(path.read_text().splitlines()), FILE_LINES.get(name, MODULE_LINES)
        if lines > limit:
            found.append((lines, name, limit))
    return sorted(found, reverse=True)


def over_limits(src: Path) -> list[str]:
    """Every place over a limit, one line each."""
    return ([f'{lines} lines: {where} (limit {FUNCTION_LINES})' for lines, where in long_functions(src)]
            + [f'{lines} lines: {name} (limit {limit})' for lines, name, limit in long_modules(src)])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--root', type=Path, default=Path(__file__).resolve().parents[1], help='the repository')
    src = parser.parse_args().root / 'src'
    for name, limit in FILE_LINES.items():
        print(f'{name}: {len((src / name).read_text().splitlines())} lines (limit {limit})')
    over = over_limits(src)
    print('\n'.join(over) if over else f'every function within {FUNCTION_LINES} lines, every module within '
          f'{MODULE_LINES}')
    return 1 if over else 0


if __name__ == '__main__':
    sys.exit(main())
