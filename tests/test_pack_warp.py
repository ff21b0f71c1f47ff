"""benchmarks/pack_warp.py: the fat binary thinning keeps one architecture's machine code and the
PTX byte for byte, and the packed archive holds the wheel less what a CUDA machine never loads."""

from __future__ import annotations

import importlib.util
import io
import lzma
import struct
import subprocess
import sys
import tarfile
import zipfile

import pytest

from tests.test_benchmark_scripts import BENCHMARKS

spec = importlib.util.spec_from_file_location("pack_warp", BENCHMARKS / "pack_warp.py")
pack_warp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pack_warp)

PTX, CODE = 1, 2


def _entry(kind: int, sm: int, payload: bytes) -> bytes:
    header = bytearray(64)
    struct.pack_into("<HHIQ", header, 0, kind, 0x0101, 64, len(payload))
    struct.pack_into("<I", header, 28, sm)
    return bytes(header) + payload


def _container(*entries: bytes) -> bytes:
    body = b"".join(entries)
    return struct.pack("<IHHQ", pack_warp.FATBIN_MAGIC, 1, 16, len(body)) + body


def _elf(section_data: bytes) -> bytearray:
    """A minimal ELF64 file: the null section, `.shstrtab` and `.nv_fatbin` holding the data."""
    names = b"\0.shstrtab\0.nv_fatbin\0"
    names_at, data_at = 64, 64 + len(names)
    headers_at = data_at + len(section_data)
    elf = bytearray(64)
    elf[:4] = b"\x7fELF"
    struct.pack_into("<Q", elf, 0x28, headers_at)
    struct.pack_into("<HHH", elf, 0x3A, 64, 3, 1)
    elf += names + section_data
    for name, offset, size in ((0, 0, 0), (1, names_at, len(names)), (11, data_at, len(section_data))):
        header = bytearray(64)
        struct.pack_into("<IIQQQQ", header, 0, name, 1, 0, 0, offset, size)
        elf += header
    return elf


def _fatbin_section() -> bytes:
    first = _container(_entry(PTX, 75, b"P" * 24), _entry(CODE, 80, b"A" * 40), _entry(CODE, 90, b"B" * 40))
    second = _container(_entry(CODE, 90, b"C" * 16), _entry(CODE, 120, b"D" * 48))
    return first + bytes(8) + second  # containers are 8-byte aligned, with padding between


def test_thinning_zeroes_only_other_architectures_machine_code():
    elf = _elf(_fatbin_section())
    original = bytes(elf)
    zeroed = pack_warp.thin_fatbin(elf, keep_sm=90)
    assert zeroed == {80: 40, 120: 48}
    assert len(elf) == len(original)
    for kept in (b"P" * 24, b"B" * 40, b"C" * 16):
        assert kept in elf
    assert b"A" * 40 not in elf and b"D" * 48 not in elf
    # every byte that changed was machine code of sm_80 or sm_120, and is now zero
    changed = [i for i, (a, b) in enumerate(zip(original, elf)) if a != b]
    assert len(changed) == 40 + 48 and all(elf[i] == 0 for i in changed)


def test_thinning_refuses_an_architecture_with_no_machine_code():
    with pytest.raises(ValueError, match=r"no machine code for sm_86.*\[80, 90, 120\]"):
        pack_warp.thin_fatbin(_elf(_fatbin_section()), keep_sm=86)


def test_pack_leaves_out_the_cpu_jit_examples_and_tests(tmp_path):
    wheel = tmp_path / "warp_lang-0-py3-none-manylinux_2_28_x86_64.whl"
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr("warp/__init__.py", "version = 0\n")
        zf.writestr("warp/bin/warp.so", bytes(_elf(_fatbin_section())))
        zf.writestr("warp/bin/warp-clang.so", b"clang")
        zf.writestr("warp/examples/demo.py", "")
        zf.writestr("warp/tests/test_x.py", "")
        zf.writestr("warp_lang-0.dist-info/METADATA", "Name: warp-lang\n")
    archive = pack_warp.pack(wheel, keep_sm=90)
    with tarfile.open(fileobj=io.BytesIO(lzma.decompress(archive))) as tar:
        assert sorted(tar.getnames()) == ["warp/__init__.py", "warp/bin/warp.so",
                                          "warp_lang-0.dist-info/METADATA"]
        so = tar.extractfile("warp/bin/warp.so").read()
    assert b"B" * 40 in so and b"A" * 40 not in so
    parts = pack_warp.split(archive, first_mb=50e-6, part_mb=100e-6)
    assert b"".join(parts) == archive and len(parts[0]) == 50
    assert all(len(p) == 100 for p in parts[1:-1]) and 0 < len(parts[-1]) <= 100


def test_script_writes_numbered_parts(tmp_path):
    wheel = tmp_path / "w.whl"
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr("warp/bin/warp.so", bytes(_elf(_fatbin_section())))
        zf.writestr("warp/__init__.py", "x = 1\n" * 2000)
    out = tmp_path / "parts"
    subprocess.run([sys.executable, str(BENCHMARKS / "pack_warp.py"), str(wheel), "--out", str(out),
                    "--first-part-mb", "0.0003", "--part-mb", "0.0004"], check=True, capture_output=True)
    names = sorted(p.name for p in out.iterdir())
    n = len(names)
    assert n >= 2 and names == sorted(f"warp.tar.xz.part{k}of{n}" for k in range(1, n + 1))
    joined = b"".join((out / f"warp.tar.xz.part{k}of{n}").read_bytes() for k in range(1, n + 1))
    with tarfile.open(fileobj=io.BytesIO(lzma.decompress(joined))) as tar:
        assert "warp/__init__.py" in tar.getnames()
