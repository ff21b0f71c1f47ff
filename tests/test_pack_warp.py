"""benchmarks/pack_warp.py: the fat binary thinning keeps one architecture's machine code and the
PTX byte for byte, and the packed archive holds the wheel less what a CUDA machine never loads."""

from __future__ import annotations

import importlib.util
import io
import lzma
import os
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


def test_thinning_refuses_malformed_fat_binaries_instead_of_looping_or_growing_the_file():
    entry = _entry(CODE, 80, b"A" * 40)
    overlong = bytearray(entry)
    struct.pack_into("<Q", overlong, 8, 10_000)  # a payload past its container
    empty_header = bytearray(_container(entry))
    struct.pack_into("<H", empty_header, 6, 0)  # a container header of 0 bytes
    for section_data in (_container(bytes(overlong)), bytes(empty_header)):
        elf = _elf(section_data)
        size = len(elf)
        with pytest.raises(ValueError, match="runs past its"):
            pack_warp.thin_fatbin(elf, keep_sm=90)
        assert len(elf) == size


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


def _source_prelude(repo, site) -> subprocess.CompletedProcess:
    script = f'source {BENCHMARKS / "device_prelude.sh"} || exit 7; echo "PYTHONPATH=$PYTHONPATH"'
    env = {"PATH": os.environ["PATH"], "SPECRL_SITE": str(site)}
    return subprocess.run(["bash", "-c", script], cwd=repo, env=env, capture_output=True, text=True, check=False)


def test_the_prelude_unpacks_warp_once_every_part_has_arrived(tmp_path):
    """Parts carried one per call: nothing installed until the last arrives, a leftover part of
    another packing dropped, then the archive unpacked once; a corrupt set refused."""
    archive = io.BytesIO()
    with tarfile.open(fileobj=archive, mode="w") as tar:
        for name, text in (("warp/__init__.py", b"version = 1\n"), ("warp/bin/warp.so", b"\x7fELF" * 999)):
            info = tarfile.TarInfo(name)
            info.size = len(text)
            tar.addfile(info, io.BytesIO(text))
    parts = pack_warp.split(lzma.compress(archive.getvalue(), format=lzma.FORMAT_XZ), 100e-6, 100e-6)
    n = len(parts)
    assert n >= 2
    repo, site = tmp_path / "repo", tmp_path / "site"
    (repo / ".whl").mkdir(parents=True)  # no wheels: the site's install is marked done below
    site.mkdir()
    (site / ".installed").touch()
    leftovers = tmp_path / "site.warp_parts"
    leftovers.mkdir()
    (leftovers / f"warp.tar.xz.part1of{n + 1}").write_bytes(b"another packing")
    (repo / ".warp").mkdir()
    for k, part in enumerate(parts, 1):
        for old in (repo / ".warp").iterdir():
            old.unlink()
        (repo / ".warp" / f"warp.tar.xz.part{k}of{n}").write_bytes(part)
        done = _source_prelude(repo, site)
        assert done.returncode == 0, done.stderr
        assert f"PYTHONPATH={site}:{repo}" in done.stdout
        installed = (site / ".warp_installed").exists()
        assert installed == (k == n), (k, done.stdout)
        if k < n:
            assert f"{k} of {n} parts here" in done.stdout
    assert (site / "warp" / "__init__.py").read_bytes() == b"version = 1\n"
    assert sorted(p.name for p in leftovers.iterdir()) == [f"warp.tar.xz.part{k}of{n}" for k in range(1, n + 1)]
    # a set whose last part is corrupt (another packing's) unpacks nothing
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / ".installed").touch()
    for k, part in enumerate(parts, 1):
        for old in (repo / ".warp").iterdir():
            old.unlink()
        (repo / ".warp" / f"warp.tar.xz.part{k}of{n}").write_bytes(part if k < n else part[::-1])
        done = _source_prelude(repo, fresh)
    assert done.returncode == 7 and "did not unpack" in done.stderr
    assert not (fresh / ".warp_installed").exists() and not (fresh / "warp").exists()
