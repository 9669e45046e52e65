"""Many runs in a process pool, each finished run a row of a CSV file at once: Ctrl-C or a crash keeps every
finished row, and the same command again runs only the jobs whose rows are missing. And the one interval the
benchmarks put on a mean over runs."""
from __future__ import annotations

import csv
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Sequence

from uav_flock_tools.study.summary import interval  # noqa: F401 (the benchmarks' interval, resumable.interval)


def rows(path: str) -> list[dict[str, str]]:
    """The rows the CSV holds (none if it does not exist)."""
    if not os.path.exists(path):
        return []
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def sweep(path: str, fields: Sequence[str], jobs: Sequence[Any], run: Callable[[Any], dict[str, object]],
          workers: int, done: list[dict[str, str]]) -> list[dict[str, str]]:
    """Run every job (run(job) gives its row) and append each row to path as it finishes; done and the new rows."""
    print(f'{len(jobs)} runs to go ({len(done)} in {path}), {workers} processes', flush=True)
    t0 = time.perf_counter()
    new = not done
    with open(path, 'a', newline='') as f, ProcessPoolExecutor(max_workers=workers) as pool:
        out = csv.DictWriter(f, fieldnames=list(fields))
        if new:
            out.writeheader()
        futures = [pool.submit(run, job) for job in jobs]
        try:
            for i, fut in enumerate(as_completed(futures), 1):
                row = {k: ('' if v is None else v) for k, v in fut.result().items()}
                out.writerow(row)
                f.flush()
                done.append({k: str(v) for k, v in row.items()})
                if i % 10 == 0 or i == len(jobs):
                    left = (time.perf_counter() - t0) / i * (len(jobs) - i)
                    print(f'  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s, about {left / 60:.0f} min left',
                          flush=True)
        except KeyboardInterrupt:
            for fut in futures:
                fut.cancel()
            print(f'interrupted: {len(done)} rows kept in {path}; the same command goes on from there')
            raise SystemExit(130)
    return done
