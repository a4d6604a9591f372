"""
Generated pages of benchmark results: the machine-and-versions header, and the page itself.

The pages under ``docs/`` that hold measured figures are written by the benchmarks,
never by hand: ``docs/performance.md`` by ``bench/run_all.py`` (``./dev.sh bench``)
and ``docs/accuracy_study.md`` by ``bench/accuracy_study.py``. Each starts with
:func:`header`: when (UTC), on what (CPU, architecture, cores, kernel), with what
(python, numpy, scipy, numba, mujoco) and at which commit.

:func:`performance_page` assembles ``docs/performance.md`` from the tables the
benchmarks wrote into ``bench/out/``: each under a heading naming the command
that reproduces it, and a table this run did not write (skipped, failed) is
named as missing with the reason, never filled in from an older run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import datetime
from importlib import metadata
import os
from pathlib import Path
import platform
import re
import subprocess
from typing import Optional

ROOT = Path(__file__).resolve().parents[1]


def _version(module: str) -> str:
    try:
        return metadata.version(module)
    except metadata.PackageNotFoundError:
        return 'not installed'


def cpu_model() -> str:
    """Return the CPU model from /proc/cpuinfo (else what :mod:`platform` knows)."""
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def commit() -> str:
    """Return the short commit of this checkout, marked when the package differs from it."""
    try:
        head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', '--', 'rigid_body_sim'],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'
    return head + (' (rigid_body_sim/ modified)' if dirty else '')


def header(when: Optional[datetime.datetime] = None) -> str:
    """
    Return one line: date (UTC), machine, versions and commit.

    ``when``: the time to state (default: now).
    """
    when = when or datetime.datetime.now(datetime.timezone.utc)
    versions = ', '.join(f'{name} {_version(name)}'
                         for name in ('numpy', 'scipy', 'numba', 'mujoco'))
    return (f'{when.astimezone(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; {cpu_model()}, '
            f'{platform.machine()}, {os.cpu_count()} cores, {platform.system()} '
            f'{platform.release()}; python {platform.python_version()}, {versions}; '
            f'rigid_body_sim {commit()}')


def load() -> str:
    """Return the 1-minute load average against the core count, e.g. ``1.9 on 2 cores``."""
    try:
        return f'{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores'
    except OSError:
        return 'unknown'


@dataclass
class Table:
    """One table a benchmark writes into ``bench/out/``."""

    file: str
    caption: str = ''


@dataclass
class Section:
    """
    One benchmark's tables on the page.

    ``command``: what reproduces them; ``skipped``: why this run did not run it
    (a flag), or ``failed``: what went wrong; either leaves its tables out.
    """

    title: str
    command: str
    tables: list
    about: str = ''
    skipped: str = ''
    failed: str = ''
    extra: list = field(default_factory=list)


def _demote(text: str, levels: int) -> str:
    """Push every Markdown heading of ``text`` down by ``levels`` (at most to ######)."""
    return re.sub(r'^(#{1,6}) ', lambda m: '#' * min(6, len(m.group(1)) + levels) + ' ',
                  text, flags=re.M)


def _table_text(path: Path, since: float) -> Optional[str]:
    """Return the file's text without its top heading if this run wrote it, else None."""
    try:
        if path.stat().st_mtime < since:
            return None
        text = path.read_text().strip()
    except OSError:
        return None
    lines = text.splitlines()
    if lines and lines[0].startswith('# '):
        text = '\n'.join(lines[1:]).strip()
    return _demote(text, 1)


def performance_page(sections: list, out: Path, since: float, command: str,
                     started: str, load_start: str) -> str:
    """
    Return ``docs/performance.md``: the header, then each section's tables.

    Parameters
    ----------
    sections : list of Section
        The benchmarks, in the page's order.
    out : Path
        Where the benchmarks wrote their tables (``bench/out``).
    since : float
        The run's start (``time.time()``): older files are not this run's.
    command : str
        The command that wrote the page.
    started : str
        :func:`header` at the start of the run.
    load_start : str
        :func:`load` at the start of the run.

    Returns
    -------
    str
        The page's Markdown.

    """
    lines = [
        '# Performance: measured figures', '',
        f'{started}.', '',
        f'Generated by `{command}` (`bench/run_all.py`); do not edit: run it again. '
        f'Load average at the start {load_start}, at the end {load()}.', '',
        'Every timing here is wall time on the machine above, measured in one run. Read '
        'them as ratios of variants measured side by side in that run (methods, sizes, '
        'this core against MuJoCo), not as absolute figures: on a shared or loaded machine '
        'absolute times move by tens of percent between runs, and a `--quick` run '
        '(shorter spans, fewer sizes and repetitions) is noisier still. Errors, '
        'violations and work counts do not depend on the load. No test asserts a time.', '',
        'Contents: ' + ', '.join(f'[{s.title}](#{_anchor(s.title)})' for s in sections)
        + '.', '']
    for s in sections:
        lines += [f'## {s.title}', '', f'Reproduce: `{s.command}`', '']
        if s.about:
            lines += [s.about, '']
        if s.skipped or s.failed:
            why = f'skipped in this run ({s.skipped})' if s.skipped else \
                f'failed in this run: {s.failed}'
            lines += [f'Not measured: {why}. Run the command above for these tables.', '']
            continue
        for table in s.tables:
            text = _table_text(out / table.file, since)
            if table.caption:
                lines += [f'### {table.caption}', '']
            lines += [text if text is not None else
                      f'*Not produced by this run: the benchmark did not write '
                      f'`bench/out/{table.file}`.*', '']
        lines += s.extra
    return '\n'.join(lines).rstrip() + '\n'


def _anchor(title: str) -> str:
    """Return the anchor GitHub gives a heading: lower case, no punctuation, dashes."""
    return re.sub(r'[^\w\- ]', '', title.lower()).replace(' ', '-')
