"""Toolchain discovery, version checks and `toolchain install` against a local HTTP server."""

from __future__ import annotations

import hashlib
import io
import random
import tarfile
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from wftool.cli import main
from wftool.errors import ToolchainError, UsageError
from wftool.firmware import toolchain
from wftool.firmware.toolchain import SdkRelease

ARCHIVE_NAME = "arm-gnu-toolchain-99.1.rel1-x86_64-arm-none-eabi.tar.xz"
TOP = "arm-gnu-toolchain-99.1.rel1-x86_64-arm-none-eabi"

TOOLS_MK = """\
GCC_REQUIRED_VERSION ?= 13.3.1

ifeq ($(OSFAMILY)-$(ARCHFAMILY), linux-x86_64)
  ARM_SDK_URL := https://example.invalid/gnu/13.3.rel1/binrel/arm-gnu-toolchain-13.3.rel1-x86_64-arm-none-eabi.tar.xz
  DL_CHECKSUM = 0601a9588bc5b9c99ad2b56133b7f118
else ifeq ($(OSFAMILY)-$(ARCHFAMILY), macosx-arm64)
  ARM_SDK_URL := https://example.invalid/gnu/13.3.rel1/binrel/arm-gnu-toolchain-13.3.rel1-darwin-arm64-arm-none-eabi.tar.xz
  DL_CHECKSUM = f1c18320bb3121fa89dca11399273f4e
else ifeq ($(OSFAMILY), windows)
  ARM_SDK_URL := https://example.invalid/gnu/13.3.rel1/binrel/arm-gnu-toolchain-13.3.rel1-mingw-w64-i686-arm-none-eabi.zip
  DL_CHECKSUM = 39d9882ca0eb475e81170ae826c1435d
else
  $(error No toolchain URL defined for $(OSFAMILY)-$(ARCHFAMILY))
endif
"""


def fake_gcc(directory: Path, version: str) -> Path:
    """An executable arm-none-eabi-gcc that only reports VERSION."""
    directory.mkdir(parents=True, exist_ok=True)
    gcc = directory / "arm-none-eabi-gcc"
    gcc.write_text(f"#!/bin/sh\necho {version}\n")
    gcc.chmod(0o755)
    return gcc


def build_archive() -> bytes:
    """A small .tar.xz laid out like ARM's: one top directory with bin/arm-none-eabi-gcc."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:xz") as archive:
        script = b"#!/bin/sh\necho 99.1.1\n"
        member = tarfile.TarInfo(f"{TOP}/bin/arm-none-eabi-gcc")
        member.size, member.mode = len(script), 0o755
        archive.addfile(member, io.BytesIO(script))
        filler = random.Random(0).randbytes(200_000)  # incompressible: the archive stays big
        member = tarfile.TarInfo(f"{TOP}/share/filler.bin")
        member.size = len(filler)
        archive.addfile(member, io.BytesIO(filler))
    return buffer.getvalue()


class ArchiveServer:
    """Serves one file over HTTP on 127.0.0.1, honouring Range (or not), logging requests."""

    def __init__(self, body: bytes, *, ranges: bool = True) -> None:
        self.body = body
        self.ranges = ranges
        self.range_headers: list[str | None] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                header = self.headers.get("Range")
                server.range_headers.append(header)
                body, status = server.body, 200
                if header and server.ranges:
                    start = int(header.removeprefix("bytes=").split("-")[0])
                    if start >= len(body):
                        self.send_response(416)
                        self.end_headers()
                        return
                    status = 206
                    self.send_response(status)
                    self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
                    body = body[start:]
                else:
                    self.send_response(status)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(
            target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/downloads/{ARCHIVE_NAME}"

    def __enter__(self) -> ArchiveServer:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def archive() -> bytes:
    return build_archive()


@pytest.fixture
def server(archive: bytes) -> Iterator[ArchiveServer]:
    with ArchiveServer(archive) as running:
        yield running


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_install_downloads_verifies_and_unpacks(server, archive, tmp_path):
    installed = toolchain.install(
        SdkRelease(server.url, None), sha256=sha256(archive), cache=tmp_path
    )

    assert installed == tmp_path / TOP
    assert toolchain.gcc_version(installed / "bin" / "arm-none-eabi-gcc") == "99.1.1"
    assert not (tmp_path / ".downloads" / f"{ARCHIVE_NAME}.part").exists()
    assert [path.name for path in tmp_path.iterdir() if path.name != ".downloads"] == [TOP]


def test_install_resumes_a_partial_download(server, archive, tmp_path):
    part = tmp_path / ".downloads" / f"{ARCHIVE_NAME}.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(archive[:5000])

    toolchain.install(SdkRelease(server.url, None), sha256=sha256(archive), cache=tmp_path)

    assert server.range_headers == ["bytes=5000-"]
    assert (tmp_path / TOP / "bin" / "arm-none-eabi-gcc").is_file()


def test_server_without_range_support_restarts_cleanly(archive, tmp_path):
    part = tmp_path / ".downloads" / f"{ARCHIVE_NAME}.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(b"garbage that is not a prefix")
    with ArchiveServer(archive, ranges=False) as plain:
        toolchain.install(SdkRelease(plain.url, None), sha256=sha256(archive), cache=tmp_path)
    assert (tmp_path / TOP / "bin" / "arm-none-eabi-gcc").is_file()


def test_mismatching_download_is_deleted_and_not_installed(server, archive, tmp_path):
    with pytest.raises(ToolchainError, match="the download was deleted"):
        toolchain.install(SdkRelease(server.url, None), sha256="0" * 64, cache=tmp_path)

    assert not (tmp_path / ".downloads" / f"{ARCHIVE_NAME}.part").exists()
    assert not (tmp_path / TOP).exists()


def test_md5_from_the_tree_is_checked_too(server, archive, tmp_path):
    with pytest.raises(ToolchainError, match="MD5"):
        toolchain.install(SdkRelease(server.url, "0" * 32), sha256=sha256(archive), cache=tmp_path)
    assert not (tmp_path / TOP).exists()


def test_unpinned_archive_needs_an_explicit_sha256(server, tmp_path):
    with pytest.raises(ToolchainError, match="--sha256"):
        toolchain.install(SdkRelease(server.url, None), cache=tmp_path)
    assert server.range_headers == []


def test_a_cached_toolchain_is_checked_against_the_sha256(server, archive, tmp_path):
    release = SdkRelease(server.url, None)
    installed = toolchain.install(release, sha256=sha256(archive), cache=tmp_path)
    downloads = len(server.range_headers)

    assert toolchain.install(release, sha256=sha256(archive), cache=tmp_path) == installed
    with pytest.raises(ToolchainError) as wrong:
        toolchain.install(release, sha256="0" * 64, cache=tmp_path)
    assert str(wrong.value) == (
        f"the cached toolchain {installed} was unpacked from an archive with SHA-256 "
        f"{sha256(archive)}, not {'0' * 64}; delete that directory and run "
        "`wftool toolchain install` again"
    )
    (installed / toolchain.ARCHIVE_RECORD).unlink()  # e.g. copied in by hand
    with pytest.raises(ToolchainError, match="has no record of the archive it came from"):
        toolchain.install(release, sha256=sha256(archive), cache=tmp_path)
    assert len(server.range_headers) == downloads  # checked, never fetched again


def test_a_build_uses_a_cached_toolchain_only_if_its_record_checks_out(tmp_path, monkeypatch):
    pinned, sha = next(iter(toolchain.PINNED_SHA256.items()))
    directory = SdkRelease(pinned, None).directory_name
    cached = tmp_path / "wftool" / "toolchains" / directory
    fake_gcc(cached / "bin", "13.3.1")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv(toolchain.TOOLCHAIN_ENV, raising=False)
    (cached / toolchain.ARCHIVE_RECORD).write_text(f"{'1' * 64}  {pinned}\n")
    with pytest.raises(ToolchainError, match=f"SHA-256 {'1' * 64}, not {sha}"):
        toolchain.find_arm_toolchain("13.3.1", installed=directory)
    (cached / toolchain.ARCHIVE_RECORD).write_text(f"{sha}  {pinned}\n")
    assert toolchain.find_arm_toolchain("13.3.1", installed=directory).gcc.parent == cached / "bin"


@pytest.mark.parametrize("given", ["xyz", "0" * 63, "g" * 64])
def test_a_malformed_sha256_is_refused_before_downloading(server, tmp_path, given):
    with pytest.raises(UsageError, match=f"--sha256 '{given}': expected 64 hexadecimal digits"):
        toolchain.install(SdkRelease(server.url, None), sha256=given, cache=tmp_path)
    assert server.range_headers == []


def test_interrupted_download_keeps_the_part_for_resuming(tmp_path):
    with pytest.raises(ToolchainError, match="run the command again to resume"):
        toolchain.install(
            SdkRelease(f"http://127.0.0.1:9/{ARCHIVE_NAME}", None), sha256="0" * 64, cache=tmp_path
        )
    assert not (tmp_path / TOP).exists()


def test_pinned_values_cover_what_the_tree_names():
    for host in (("Linux", "x86_64"), ("Darwin", "arm64"), ("Windows", "AMD64")):
        release = toolchain.sdk_release(TOOLS_MK, *host)
        assert release.file_name in toolchain.PINNED_SHA256
    release = toolchain.sdk_release(TOOLS_MK, "Linux", "x86_64")
    assert release.md5 == "0601a9588bc5b9c99ad2b56133b7f118"
    assert release.directory_name == "arm-gnu-toolchain-13.3.rel1-x86_64-arm-none-eabi"


def test_unknown_host_is_an_error():
    with pytest.raises(ToolchainError, match="linux-riscv64"):
        toolchain.sdk_release(TOOLS_MK, "Linux", "riscv64")


def test_required_version_comes_from_tools_mk():
    assert toolchain.required_version(TOOLS_MK) == "13.3.1"


def test_explicit_toolchain_dir_and_version_check(tmp_path):
    fake_gcc(tmp_path / "tc" / "bin", "12.2.1")

    found = toolchain.find_arm_toolchain("13.3.1", explicit=tmp_path / "tc")

    assert found.gcc == tmp_path / "tc" / "bin" / "arm-none-eabi-gcc"
    assert found.version == "12.2.1"
    assert not found.matches
    assert found.prefix == str(tmp_path / "tc" / "bin" / "arm-none-eabi-")
    with pytest.raises(ToolchainError, match="strict-toolchain"):
        toolchain.find_arm_toolchain("13.3.1", explicit=tmp_path / "tc", strict=True)
    assert toolchain.find_arm_toolchain("12.2.1", explicit=tmp_path / "tc", strict=True).matches


def test_search_order_env_then_cache_then_path(tmp_path, monkeypatch):
    fake_gcc(tmp_path / "env", "1.0.0")
    fake_gcc(tmp_path / "cache" / "wftool" / "toolchains" / "rel" / "bin", "2.0.0")
    record = tmp_path / "cache" / "wftool" / "toolchains" / "rel" / toolchain.ARCHIVE_RECORD
    record.write_text(f"{'2' * 64}  rel.tar.xz\n")  # as `install` leaves it
    fake_gcc(tmp_path / "path", "3.0.0")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("PATH", str(tmp_path / "path"))

    monkeypatch.setenv(toolchain.TOOLCHAIN_ENV, str(tmp_path / "env"))
    assert toolchain.find_arm_toolchain("1.0.0", installed="rel").version == "1.0.0"
    monkeypatch.delenv(toolchain.TOOLCHAIN_ENV)
    assert toolchain.find_arm_toolchain("1.0.0", installed="rel").version == "2.0.0"
    assert toolchain.find_arm_toolchain("1.0.0", installed="other").version == "3.0.0"
    monkeypatch.setenv("PATH", str(tmp_path / "nowhere"))
    with pytest.raises(ToolchainError, match="not found"):
        toolchain.find_arm_toolchain("1.0.0")


def test_cache_dir_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert toolchain.cache_dir() == tmp_path / "wftool" / "toolchains"


def test_cli_install_from_a_mirror(server, archive, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    args = ["toolchain", "install", "--url", server.url]

    with pytest.raises(SystemExit) as refused:
        main(args)
    assert refused.value.code == 1
    assert "no SHA-256 is pinned" in capsys.readouterr().err

    with pytest.raises(SystemExit) as installed:
        main([*args, "--sha256", sha256(archive)])
    assert installed.value.code == 0
    assert f"toolchain ready: {tmp_path / 'wftool' / 'toolchains' / TOP}" in capsys.readouterr().out

    with pytest.raises(SystemExit) as mismatch:  # the cache is there now, and checked
        main([*args, "--sha256", "0" * 64])
    assert mismatch.value.code == 1
    captured = capsys.readouterr()
    assert "ready" not in captured.out
    assert captured.err.startswith("error: the cached toolchain ")
    with pytest.raises(SystemExit) as malformed:
        main([*args, "--sha256", "xyz"])
    assert malformed.value.code == 2
    assert capsys.readouterr().err == ("error: --sha256 'xyz': expected 64 hexadecimal digits\n")
