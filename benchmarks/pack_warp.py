"""Packs the warp-lang wheel (MuJoCo Warp's kernels: Car's and Ant's GPU physics) into parts small
enough to travel to the lent GPU machine beside the working tree, one part per call.

The wheel is 149 MB and unpacks to 390 MB. What a CUDA machine never loads is left out: the CPU
JIT (`warp/bin/warp-clang.so`, without which Warp runs with CUDA devices alone), the examples and
the tests. The CUDA fat binary in `warp/bin/warp.so` holds Warp's own kernels as machine code for
seven GPU architectures and as PTX; the machine code of every architecture but `--sm` is zeroed in
place (the file keeps its layout, and the driver picks the `--sm` code), which the compressor then
drops. The result is for GPUs of that one architecture (90: H100, H200): pack again with another
`--sm` for another GPU. xz with the x86 branch filter packs the rest to about 59 MB.

Usage: python benchmarks/pack_warp.py .whl/warp_lang-1.19.0-*.whl   (writes .warp/warp.tar.xz.part1of2 ...)
On the GPU machine `benchmarks/device_prelude.sh` keeps each part it is carried and unpacks the
archive once every part has arrived.
"""

from __future__ import annotations

import argparse
import io
import lzma
import struct
import tarfile
import zipfile
from pathlib import Path

FATBIN_MAGIC = 0xBA55ED50
ELF_CODE = 2  # a fat binary entry's kind: 1 PTX, 2 machine code (an ELF cubin)
LEFT_OUT = ("warp/bin/warp-clang.so", "warp/examples/", "warp/tests/")


def section(elf: bytes, name: str) -> tuple[int, int]:
    """(file offset, size) of the ELF64 section `name`."""
    shoff, = struct.unpack_from("<Q", elf, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", elf, 0x3A)
    headers = [struct.unpack_from("<IIQQQQ", elf, shoff + i * shentsize) for i in range(shnum)]
    names_offset = headers[shstrndx][4]
    for name_at, _, _, _, offset, size in headers:
        start = names_offset + name_at
        if elf[start:elf.index(b"\0", start)].decode() == name:
            return offset, size
    raise ValueError(f"no section {name} in this ELF file")


def thin_fatbin(elf: bytearray, keep_sm: int) -> dict[int, int]:
    """Zero, in place, the machine code of every architecture but `keep_sm` in the fat binaries
    of `elf`'s `.nv_fatbin` section; returns bytes zeroed per architecture. The zeroed entries
    keep their headers, so the result loads on a `keep_sm` GPU only."""
    start, size = section(bytes(elf), ".nv_fatbin")
    zeroed: dict[int, int] = {}
    seen: set[int] = set()
    pos, end = start, start + size
    while pos + 16 <= end:
        magic, _, header, fat_size = struct.unpack_from("<IHHQ", elf, pos)
        if magic != FATBIN_MAGIC:
            pos += 8  # containers start 8-byte aligned in the section
            continue
        entry, container_end = pos + header, pos + header + fat_size
        if header < 16 or container_end > end:
            raise ValueError(f"a fat binary container at byte {pos} runs past its section "
                             f"(or has a header of {header} bytes)")
        while entry < container_end:
            kind, _, entry_header, payload = struct.unpack_from("<HHIQ", elf, entry)
            sm, = struct.unpack_from("<I", elf, entry + 28)
            body = entry + entry_header
            if entry_header < 32 or body + payload > container_end:
                raise ValueError(f"a fat binary entry at byte {entry} runs past its container")
            if kind == ELF_CODE:
                seen.add(sm)
                if sm != keep_sm:
                    elf[body:body + payload] = bytes(payload)
                    zeroed[sm] = zeroed.get(sm, 0) + payload
            entry = body + payload
        pos = start + -(-(container_end - start) // 8) * 8
    if keep_sm not in seen:
        raise ValueError(f"no machine code for sm_{keep_sm} in the fat binaries; found sm_{sorted(seen)}")
    return zeroed


def pack(wheel: Path, keep_sm: int) -> bytes:
    """The wheel's files, less `LEFT_OUT`, with `warp.so` thinned, as an xz-compressed tar."""
    raw = io.BytesIO()
    with zipfile.ZipFile(wheel) as zf, tarfile.open(fileobj=raw, mode="w") as tar:
        for info in zf.infolist():
            if info.is_dir() or info.filename.startswith(LEFT_OUT):
                continue
            data = bytearray(zf.read(info))
            if info.filename == "warp/bin/warp.so":
                zeroed = thin_fatbin(data, keep_sm)
                print(f"warp.so: zeroed {sum(zeroed.values()) / 1e6:.1f} MB of machine code for "
                      f"sm_{', sm_'.join(map(str, sorted(zeroed)))}; kept sm_{keep_sm} and the PTX")
            member = tarfile.TarInfo(info.filename)
            member.size, member.mode = len(data), 0o755 if info.filename.endswith(".so") else 0o644
            tar.addfile(member, io.BytesIO(bytes(data)))
    filters = [{"id": lzma.FILTER_X86},
               {"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME, "dict_size": 192 << 20}]
    return lzma.compress(raw.getvalue(), format=lzma.FORMAT_XZ, filters=filters)


def split(archive: bytes, first_mb: float, part_mb: float) -> list[bytes]:
    """`archive` cut into a first part of `first_mb` MB and further parts of `part_mb` MB."""
    if first_mb <= 0 or part_mb <= 0:
        raise ValueError(f"part sizes must be positive, got {first_mb} and {part_mb} MB")
    cuts, at, size = [], 0, int(first_mb * 1e6)
    while at < len(archive):
        cuts.append(archive[at:at + size])
        at, size = at + size, int(part_mb * 1e6)
    return cuts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("wheel", type=Path, help="the warp-lang manylinux x86_64 wheel")
    parser.add_argument("--sm", type=int, default=90, help="the GPU architecture kept (90: H100, H200)")
    parser.add_argument("--first-part-mb", type=float, default=27.0,
                        help="the first part travels with .site (about 10 MB) and the tree (about 29 MB)")
    parser.add_argument("--part-mb", type=float, default=37.0, help="each later part travels with the tree alone")
    parser.add_argument("--out", type=Path, default=Path(".warp"))
    args = parser.parse_args()
    parts = split(pack(args.wheel, args.sm), args.first_part_mb, args.part_mb)
    args.out.mkdir(parents=True, exist_ok=True)
    for old in args.out.glob("warp.tar.xz.part*"):
        old.unlink()
    for i, part in enumerate(parts, 1):
        path = args.out / f"warp.tar.xz.part{i}of{len(parts)}"
        path.write_bytes(part)
        print(f"{path}: {len(part) / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
