"""A wheel too large for one carry to the GPU machine, sent in parts and joined there.

The device tool carries at most 64 MiB a call, the working tree included, and keeps what a call
leaves in an ignored folder for the next call while the machine is warm (about 30 s).
onnxruntime-gpu's wheel (243.7 MiB) therefore travels as parts over consecutive calls, each
call carrying one part into ``.ortparts/``, and the last one joins them (checking each part's
and the whole wheel's SHA-256 against the manifest) before the GPU check installs it with the
other wheels (docs/gpu.md, "onnxruntime-gpu in parts").

    python -m benchmarks.wheel_parts split WHEEL DIR [--part-mib 40]
    python -m benchmarks.wheel_parts join DIR OUT_DIR
    python -m benchmarks.wheel_parts calls DIR [--check-out DIR]

``split`` writes ``DIR/part-01.bin`` ... and ``DIR/manifest.json`` (the wheel's name, size and
SHA-256, and each part's). ``join`` writes ``OUT_DIR/<wheel name>``; a part missing, of another
size or another digest, or a joined wheel whose digest is not the manifest's, is one line on
stderr and exit status 2, and nothing is written. ``calls`` prints the device calls, one line
each: the paths to carry and the command (the last joins, then runs the GPU check).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['PartsError', 'calls', 'join', 'main', 'split']

MIB = 1 << 20
MANIFEST = 'manifest.json'
#: a part and the working tree (some 17 MiB tracked) fit one 64 MiB carry
DEFAULT_PART_MIB = 40
_CHUNK = 4 * MIB


class PartsError(Exception):
    """Parts that cannot be joined (or a wheel that cannot be split), in one line."""


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with path.open('rb') as f:
        while block := f.read(_CHUNK):
            h.update(block)
    return h.hexdigest()


def split(wheel: Path, out: Path, part_mib: int = DEFAULT_PART_MIB) -> dict[str, Any]:
    """``wheel`` cut into parts of at most ``part_mib`` MiB in ``out`` with their manifest;
    returns the manifest."""
    if part_mib < 1:
        msg = f'--part-mib must be at least 1, not {part_mib}'
        raise PartsError(msg)
    if not wheel.is_file():
        msg = f'{wheel}: no such file'
        raise PartsError(msg)
    out.mkdir(parents=True, exist_ok=True)
    size = part_mib * MIB
    parts: list[dict[str, Any]] = []
    with wheel.open('rb') as f:
        while block := f.read(size):
            name = f'part-{len(parts) + 1:02d}.bin'
            (out / name).write_bytes(block)
            parts.append(
                {'name': name, 'size': len(block), 'sha256': hashlib.sha256(block).hexdigest()}
            )
    manifest = {
        'wheel': wheel.name,
        'size': wheel.stat().st_size,
        'sha256': _digest(wheel),
        'part_mib': part_mib,
        'parts': parts,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1) + '\n', encoding='utf-8')
    return manifest


def _manifest(folder: Path) -> dict[str, Any]:
    path = folder / MANIFEST
    try:
        manifest: dict[str, Any] = json.loads(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        msg = f'{path}: no manifest (split writes it beside the parts)'
        raise PartsError(msg) from None
    except (OSError, ValueError) as err:
        msg = f'{path}: cannot read the manifest: {err}'
        raise PartsError(msg) from None
    return manifest


def join(folder: Path, out: Path) -> Path:
    """The wheel of ``folder``'s parts, written to ``out`` once every part and the whole are
    what the manifest says; ``PartsError`` (nothing written) otherwise."""
    manifest = _manifest(folder)
    out.mkdir(parents=True, exist_ok=True)
    target: Path = out / str(manifest['wheel'])
    partial = target.with_name(target.name + '.partial')
    whole = hashlib.sha256()
    try:
        with partial.open('wb') as f:  # each part read once: checked, hashed, written
            for part in manifest['parts']:
                path = folder / part['name']
                if not path.is_file():
                    msg = f'{path}: part missing ({len(manifest["parts"])} parts in the manifest)'
                    raise PartsError(msg)
                data = path.read_bytes()
                digest = hashlib.sha256(data).hexdigest()
                if len(data) != part['size'] or digest != part['sha256']:
                    msg = f'{path}: not the part the manifest names (size or SHA-256 differs)'
                    raise PartsError(msg)
                whole.update(data)
                f.write(data)
        if whole.hexdigest() != manifest['sha256']:
            msg = f'{folder}: the joined parts are not {manifest["wheel"]} (SHA-256 differs)'
            raise PartsError(msg)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    partial.replace(target)
    return target


def calls(folder: Path, check_out: str = '$OUT') -> list[tuple[list[str], str]]:
    """The device calls that bring ``folder``'s parts over and run the GPU check with the
    joined wheel: (paths to carry, command) each, in order. Every call but the last carries
    one part and only lists what is there; the last carries the last part and ``.whl`` (the
    other wheels), joins the parts into ``.whl`` and runs ``benchmarks/gpu_check.sh``. The
    manifest travels with the first part (with the last where there is one part)."""
    manifest = _manifest(folder)
    parts = [f'{folder.as_posix()}/{p["name"]}' for p in manifest['parts']]
    listing = f'ls -l {folder.as_posix()}'
    out: list[tuple[list[str], str]] = [([part], listing) for part in parts[:-1]]
    if out:  # the manifest with the first part
        out[0] = ([parts[0], f'{folder.as_posix()}/{MANIFEST}'], listing)
    last = (
        f'python3 -m benchmarks.wheel_parts join {folder.as_posix()} .whl && '
        f'benchmarks/gpu_check.sh --out {check_out}'
    )
    final = [parts[-1], '.whl'] if out else [parts[-1], f'{folder.as_posix()}/{MANIFEST}', '.whl']
    out.append((final, last))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.wheel_parts', description=__doc__)
    commands = parser.add_subparsers(dest='command', required=True)
    cut = commands.add_parser('split', help='cut a wheel into parts with their manifest')
    cut.add_argument('wheel', type=Path)
    cut.add_argument('out', type=Path)
    cut.add_argument('--part-mib', type=int, default=DEFAULT_PART_MIB)
    glue = commands.add_parser('join', help='check the parts and write the wheel')
    glue.add_argument('folder', type=Path)
    glue.add_argument('out', type=Path)
    plan = commands.add_parser('calls', help='print the device calls, one line each')
    plan.add_argument('folder', type=Path)
    plan.add_argument('--check-out', default='$OUT')
    args = parser.parse_args(argv)
    try:
        if args.command == 'split':
            manifest = split(args.wheel, args.out, args.part_mib)
            print(f'{manifest["wheel"]}: {len(manifest["parts"])} parts in {args.out}')
        elif args.command == 'join':
            print(join(args.folder, args.out))
        else:
            for carry, command in calls(args.folder, args.check_out):
                print(json.dumps({'carry': carry, 'command': command}))
    except PartsError as err:
        print(f'wheel_parts: error: {err}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
