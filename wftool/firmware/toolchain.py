"""The compiler: finding arm-none-eabi-gcc, checking its version, installing the pinned one.

Betaflight's mk/tools.mk names the toolchain it expects (GCC_REQUIRED_VERSION) and the ARM GNU
release to download (ARM_SDK_URL). Both are read from the pinned tree, never hardcoded; what
wftool pins itself is the SHA-256 of each release archive, because the tree only carries MD5.
"""

from __future__ import annotations

import hashlib
import os
import platform
import re
import shutil
import subprocess
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import ToolchainError, UsageError
from wftool.progress import Progress, no_progress

TOOLCHAIN_ENV = "WFTOOL_TOOLCHAIN"
"""A toolchain directory (holding bin/arm-none-eabi-gcc) to use instead of searching."""

ARM_GCC = "arm-none-eabi-gcc"

PINNED_SHA256 = {
    # ARM GNU Toolchain 13.3.rel1, the release Betaflight 2025.12 and 2026.6 name. The values
    # are those ARM publishes in the .sha256asc files beside each archive, as reproduced by
    # several independent public build recipes (nixpkgs, Homebrew formulae, Dockerfiles).
    "arm-gnu-toolchain-13.3.rel1-x86_64-arm-none-eabi.tar.xz": (
        "95c011cee430e64dd6087c75c800f04b9c49832cc1000127a92a97f9c8d83af4"
    ),
    "arm-gnu-toolchain-13.3.rel1-darwin-x86_64-arm-none-eabi.tar.xz": (
        "1ab00742d1ed0926e6f227df39d767f8efab46f5250505c29cb81f548222d794"
    ),
    "arm-gnu-toolchain-13.3.rel1-darwin-arm64-arm-none-eabi.tar.xz": (
        "fb6921db95d345dc7e5e487dd43b745e3a5b4d5c0c7ca4f707347148760317b4"
    ),
    "arm-gnu-toolchain-13.3.rel1-mingw-w64-i686-arm-none-eabi.zip": (
        "e46fda043c0ce83582bc8db4b3ef85f77f4beb7333344c2f4193c17e1167a095"
    ),
}

_REQUIRED = re.compile(r"^\s*GCC_REQUIRED_VERSION\s*\??=\s*(\S+)", re.MULTILINE)
_SDK_BLOCK = re.compile(
    r"ifeq\s*\(\$\(OSFAMILY\)(?:-\$\(ARCHFAMILY\))?,\s*(?P<host>[\w-]+)\)\s*\n"
    r"\s*ARM_SDK_URL\s*:?=\s*(?P<url>\S+)\s*\n"
    r"(?:\s*DL_CHECKSUM\s*:?=\s*(?P<md5>[0-9a-fA-F]{32}))?"
)
_ARCHIVE_SUFFIXES = (".tar.xz", ".tar.bz2", ".tar.gz", ".zip")
_SHA256 = re.compile(r"[0-9a-f]{64}")
ARCHIVE_RECORD = ".wftool-archive.sha256"
"""In an installed toolchain: the SHA-256 of the archive it was unpacked from."""
_RELEASE_VERSION = re.compile(r"^arm-gnu-toolchain-(\d+)\.(\d+)\.rel(\d+)-")
"""ARM's release X.Y.relN ships gcc X.Y.N."""


@dataclass(frozen=True)
class Toolchain:
    """The C compiler a build uses."""

    gcc: Path
    version: str
    required: str | None
    """The version the Betaflight tree asks for; None for SITL (any host gcc)."""
    strict: bool = False

    @property
    def prefix(self) -> str:
        """Betaflight's ARM_SDK_PREFIX: the compiler path without the trailing `gcc`."""
        return str(self.gcc)[: -len("gcc")]

    @property
    def matches(self) -> bool:
        """Whether the version is the one the tree asks for (always true for SITL)."""
        return self.required is None or self.version == self.required


@dataclass(frozen=True)
class SdkRelease:
    """The ARM GNU toolchain archive the pinned tree names for this host."""

    url: str
    md5: str | None

    @property
    def file_name(self) -> str:
        """The archive's file name, the key of PINNED_SHA256."""
        return self.url.split("?", 1)[0].rsplit("/", 1)[-1]

    @property
    def directory_name(self) -> str:
        """The directory it installs to: the file name without the archive suffix."""
        name = self.file_name
        for suffix in _ARCHIVE_SUFFIXES:
            name = name.removesuffix(suffix)
        return name


def cache_dir() -> Path:
    """Per-user toolchain cache: $XDG_CACHE_HOME/wftool/toolchains (~/.cache/... by default)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "wftool" / "toolchains"


def required_version(tools_mk: str) -> str:
    """GCC_REQUIRED_VERSION from the text of Betaflight's mk/tools.mk."""
    match = _REQUIRED.search(tools_mk)
    if match is None:
        raise ToolchainError("mk/tools.mk does not set GCC_REQUIRED_VERSION")
    return match.group(1)


def sdk_release(tools_mk: str, system: str | None = None, machine: str | None = None) -> SdkRelease:
    """The ARM_SDK_URL (and MD5) mk/tools.mk names for this host (Betaflight's host names)."""
    osfamily = {"Linux": "linux", "Darwin": "macosx", "Windows": "windows"}.get(
        system or platform.system(), (system or platform.system()).lower()
    )
    host = f"{osfamily}-{machine or platform.machine()}"
    for block in _SDK_BLOCK.finditer(tools_mk):
        if block.group("host") in (host, osfamily):
            return SdkRelease(block.group("url"), block.group("md5"))
    raise ToolchainError(f"the pinned Betaflight tree names no ARM toolchain for {host}")


def arm_requirement(tree: Path | None) -> tuple[str, str | None]:
    """The gcc version a build of the pinned Betaflight requires, and the directory of the
    release `install` puts in the cache for this host (None if it names none).

    Read from the tree's mk/tools.mk when TREE is checked out; else from the release wftool
    pins the SHA-256 of (the one mk/tools.mk names), so `doctor` can tell before a fetch.
    """
    tools_mk = tree / "mk" / "tools.mk" if tree is not None else None
    if tools_mk is not None and tools_mk.is_file():
        text = tools_mk.read_text()
        try:
            installed: str | None = sdk_release(text).directory_name
        except ToolchainError:  # no ARM release for this host; PATH or --toolchain must do
            installed = None
        return required_version(text), installed
    pinned = [SdkRelease(name, None).directory_name for name in PINNED_SHA256]
    versions = {m.expand(r"\1.\2.\3") for n in pinned if (m := _RELEASE_VERSION.match(n))}
    if len(versions) != 1:
        raise ToolchainError(f"the pinned ARM releases name {len(versions)} gcc versions")
    cached = (name for name in pinned if (cache_dir() / name / "bin" / ARM_GCC).is_file())
    return versions.pop(), next(cached, None)


def gcc_version(gcc: Path, flag: str = "-dumpversion") -> str:
    """The compiler's version; `-dumpversion` is what Betaflight compares with the required one."""
    try:
        proc = subprocess.run([str(gcc), flag], capture_output=True, text=True, check=False)
    except OSError as exc:
        raise ToolchainError(f"cannot run {gcc}: {exc}") from exc
    if proc.returncode != 0 or not proc.stdout.strip():
        raise ToolchainError(f"{gcc} {flag} failed")
    return proc.stdout.strip()


def find_arm_toolchain(
    required: str,
    *,
    explicit: Path | None = None,
    strict: bool = False,
    installed: str | None = None,
) -> Toolchain:
    """Find arm-none-eabi-gcc and check it against REQUIRED.

    Search order: EXPLICIT (--toolchain DIR), $WFTOOL_TOOLCHAIN, the release INSTALLED by
    `wftool toolchain install` in the cache, then PATH. A version mismatch raises under
    STRICT; otherwise the caller warns and builds anyway.
    """
    named = explicit or (Path(os.environ[TOOLCHAIN_ENV]) if os.environ.get(TOOLCHAIN_ENV) else None)
    if named is not None:
        gcc = next(
            (path for path in (named / "bin" / ARM_GCC, named / ARM_GCC) if path.is_file()), None
        )
        if gcc is None:
            raise ToolchainError(f"no {ARM_GCC} in {named} or {named / 'bin'}")
    else:
        cached = cache_dir() / installed / "bin" / ARM_GCC if installed else None
        on_path = shutil.which(ARM_GCC)
        if cached is not None and cached.is_file():
            _check_installed(cached.parent.parent, _pinned_for(cached.parent.parent.name))
            gcc = cached
        elif on_path:
            gcc = Path(on_path)
        else:
            raise ToolchainError(
                f"{ARM_GCC} not found; install it (`wftool toolchain install`, or your "
                "distribution's gcc-arm-none-eabi) or pass --toolchain DIR"
            )
    # absolute(), not resolve(): ARM_SDK_PREFIX must keep the toolchain's own bin/ directory.
    toolchain = Toolchain(gcc.absolute(), gcc_version(gcc), required, strict)
    if strict and not toolchain.matches:
        raise ToolchainError(
            f"{toolchain.gcc} is gcc {toolchain.version}, the Betaflight tree requires {required} "
            "(--strict-toolchain); `wftool toolchain install` fetches it"
        )
    return toolchain


def host_toolchain() -> Toolchain:
    """The host gcc that SITL builds with."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise ToolchainError("SITL needs the host C compiler, and gcc is not on PATH")
    return Toolchain(Path(gcc), gcc_version(Path(gcc), "-dumpfullversion"), None)


def parse_sha256(text: str) -> str:
    """A SHA-256 given by a user, lower-cased; anything but 64 hex digits is a UsageError."""
    value = text.strip().lower()
    if not _SHA256.fullmatch(value):
        raise UsageError(f"--sha256 {text!r}: expected 64 hexadecimal digits")
    return value


def install(
    release: SdkRelease,
    *,
    sha256: str | None = None,
    cache: Path | None = None,
    progress: Progress | None = None,
) -> Path:
    """Download, verify and unpack RELEASE into the cache; return the toolchain directory.

    PROGRESS gets ("download <file>", bytes so far, total bytes or None).

    The download resumes from a previous `.part` (HTTP Range). The archive must match SHA256
    (default: the pinned value for its file name; none pinned and none given is refused) and
    the tree's MD5; a mismatching download is deleted. Unpacking happens in a scratch
    directory that is renamed into place, so the cache never holds a half toolchain. The
    installed toolchain records its archive's SHA-256; one already in the cache is used only
    if that record matches.
    """
    cache = cache or cache_dir()
    expected = parse_sha256(sha256) if sha256 else PINNED_SHA256.get(release.file_name, "")
    if not expected:
        raise ToolchainError(
            f"no SHA-256 is pinned for {release.file_name}; check ARM's published "
            ".sha256asc and pass --sha256 HEX"
        )
    destination = cache / release.directory_name
    if destination.is_dir():
        _check_installed(destination, expected)
        return destination
    downloads = cache / ".downloads"
    downloads.mkdir(parents=True, exist_ok=True)
    part = downloads / f"{release.file_name}.part"
    _download(release.url, part, progress or no_progress)
    digests = _digests(part)
    mismatch = None
    if digests["sha256"] != expected:
        mismatch = f"SHA-256 {digests['sha256']}, expected {expected}"
    elif release.md5 and digests["md5"] != release.md5.lower():
        mismatch = f"MD5 {digests['md5']}, the Betaflight tree expects {release.md5}"
    if mismatch:
        part.unlink()
        raise ToolchainError(f"{release.file_name}: {mismatch}; the download was deleted")
    scratch = Path(tempfile.mkdtemp(prefix=f".{release.directory_name}.", dir=cache))
    try:
        _unpack(part, release.file_name, scratch)
        entries = list(scratch.iterdir())
        root = entries[0] if len(entries) == 1 and entries[0].is_dir() else scratch
        (root / ARCHIVE_RECORD).write_text(f"{expected}  {release.file_name}\n")
        root.rename(destination)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    part.unlink()
    return destination


def _pinned_for(directory_name: str) -> str | None:
    """The pinned SHA-256 of the release that installs to DIRECTORY_NAME, if any."""
    return next(
        (
            sha256
            for name, sha256 in PINNED_SHA256.items()
            if SdkRelease(name, None).directory_name == directory_name
        ),
        None,
    )


def _check_installed(directory: Path, expected: str | None) -> None:
    """Refuse a cached toolchain not unpacked from the archive with SHA-256 EXPECTED (None:
    from any archive `install` verified)."""
    record = directory / ARCHIVE_RECORD
    try:
        recorded = record.read_text().split()[0]
    except (OSError, IndexError):
        recorded = ""
    if recorded and recorded == (expected or recorded):
        return
    found = (
        f"was unpacked from an archive with SHA-256 {recorded}"
        if recorded
        else "has no record of the archive it came from"
    )
    raise ToolchainError(
        f"the cached toolchain {directory} {found}"
        + (f", not {expected}" if expected else "")
        + "; delete that directory and run `wftool toolchain install` again"
    )


def _download(url: str, part: Path, progress: Progress) -> None:
    """Fetch URL into PART, continuing where an interrupted download stopped."""
    import requests  # here: its import is a seventh of every `wftool` command's start

    offset = part.stat().st_size if part.exists() else 0
    headers = {"Range": f"bytes={offset}-"} if offset else {}
    try:
        with requests.get(url, headers=headers, stream=True, timeout=30) as response:
            if response.status_code == 416:  # the .part is already complete
                return
            response.raise_for_status()
            resumed = response.status_code == 206
            if not resumed:
                offset = 0
            length = int(response.headers.get("Content-Length") or 0)
            phase = f"download {part.name.removesuffix('.part')}"
            total = offset + length if length else None
            done = offset
            progress(phase, done, total)
            with part.open("ab" if resumed else "wb") as sink:
                for chunk in response.iter_content(chunk_size=1 << 16):
                    sink.write(chunk)
                    done += len(chunk)
                    progress(phase, done, total)
    except requests.RequestException as exc:
        raise ToolchainError(
            f"download of {url} failed ({exc}); run the command again to resume"
        ) from exc


def _digests(path: Path) -> dict[str, str]:
    sha256, md5 = hashlib.sha256(), hashlib.md5()
    with path.open("rb") as source:
        while chunk := source.read(1 << 20):
            sha256.update(chunk)
            md5.update(chunk)
    return {"sha256": sha256.hexdigest(), "md5": md5.hexdigest()}


def _unpack(archive: Path, file_name: str, into: Path) -> None:
    """Extract a .tar.* or .zip, refusing members that would land outside INTO."""
    try:
        if file_name.endswith(".zip"):
            with zipfile.ZipFile(archive) as bundle:
                for member in bundle.namelist():
                    if not (into / member).resolve().is_relative_to(into.resolve()):
                        raise ToolchainError(f"{file_name}: unsafe path {member}")
                bundle.extractall(into)
        else:
            with tarfile.open(archive) as bundle:
                if hasattr(tarfile, "data_filter"):
                    bundle.extractall(into, filter="data")
                else:  # Python without extraction filters: check paths ourselves
                    for entry in bundle.getmembers():
                        if not (into / entry.name).resolve().is_relative_to(into.resolve()):
                            raise ToolchainError(f"{file_name}: unsafe path {entry.name}")
                    bundle.extractall(into)
    except (tarfile.TarError, zipfile.BadZipFile, OSError) as exc:
        raise ToolchainError(f"cannot unpack {file_name}: {exc}") from exc
