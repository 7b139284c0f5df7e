"""`build()`: from a wftool checkout to traceable firmware in build/<target>/.

The steps: make sure the Betaflight tree is there and clean (tree), put it at pin + series
(patches), pick the compiler (toolchain), run make (make), copy the outputs and write
manifest.json (manifest). Every option that changes the firmware selects its own object
directory, so switching flags never reuses objects compiled with other flags, and switching
back is free. A build whose inputs and outputs are unchanged touches nothing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shutil
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from wftool.errors import UsageError
from wftool.firmware import make, patches, toolchain, tree
from wftool.firmware.manifest import FILE_NAME, BuildFlags, Manifest, file_sha256
from wftool.firmware.project import Project, exclusive
from wftool.firmware.targets import Target, resolve_target
from wftool.firmware.toolchain import Toolchain
from wftool.progress import Log, Progress, quiet

_DEFINE = re.compile(r"^[A-Za-z_]\w*(=[\w.+-]*)?$")
"""--define NAME[=VALUE]; VALUE is kept shell-safe because make pastes it into command lines."""


@dataclass(frozen=True)
class BuildOptions:
    """How to build, beyond which target."""

    flags: BuildFlags = field(default_factory=BuildFlags)
    jobs: int | None = None
    """make -j; default: one per CPU."""
    toolchain_dir: Path | None = None
    strict_toolchain: bool = False
    clean: bool = False
    """Discard uncommitted changes and unexported commits in betaflight/ instead of refusing."""
    rebuild: bool = False
    """Delete this configuration's objects first (a from-scratch build, e.g. for benchmarks)."""
    ccache: bool = True


@dataclass(frozen=True)
class BuildResult:
    """What `build()` produced."""

    target: Target
    manifest: Manifest
    up_to_date: bool
    """Nothing was compiled or copied: the outputs already matched the inputs."""
    compiled: int
    seconds: float
    warnings: list[str]

    @property
    def manifest_path(self) -> Path:
        return self.manifest.path

    @property
    def out_dir(self) -> Path:
        """build/<target>/."""
        return self.manifest.out_dir

    @property
    def firmware(self) -> Path:
        """The file to flash (.hex) or to run (SITL)."""
        return self.manifest.firmware


@dataclass(frozen=True)
class Prepared:
    """A target ready for make: tree patched, compiler chosen, command assembled."""

    project: Project
    target: Target
    toolchain: Toolchain
    command: make.MakeCommand
    object_dir: Path
    flags: BuildFlags
    warnings: list[str]


def build(
    project: Project,
    target_name: str,
    options: BuildOptions | None = None,
    *,
    progress: Progress | None = None,
    log: Log = quiet,
) -> BuildResult:
    """Build TARGET_NAME. PROGRESS gets make's progress (`make.run`); LOG gets news: waiting
    for another run's lock, toolchain warnings (also in `BuildResult.warnings`)."""
    with exclusive(project, lambda: log("waiting for another wftool run")):
        return _build(project, target_name, options or BuildOptions(), progress, log)


def _build(
    project: Project,
    target_name: str,
    options: BuildOptions,
    progress: Progress | None,
    log: Log,
) -> BuildResult:
    started = time.monotonic()
    prepared = prepare(project, target_name, options, log)
    if options.rebuild:
        shutil.rmtree(prepared.object_dir, ignore_errors=True)
        make.write_hook(prepared.command.hook)
    _invalidate_stale_revision(prepared)
    out_dir = project.build_dir / prepared.target.name
    manifest_path = out_dir / FILE_NAME
    previous = Manifest.read(manifest_path)
    build_log = out_dir / "build.log"
    run = None
    if _stamp(prepared).exists():  # objects of a finished build: find what is out of date
        plan = make.plan(prepared.command)
        values = plan.values
        inputs = _inputs_fingerprint(prepared, values)
        if (
            plan.up_to_date
            and previous is not None
            and previous.inputs_sha256 == inputs
            and _artifacts_intact(previous)
        ):
            return BuildResult(
                target=prepared.target,
                manifest=previous,
                up_to_date=True,
                compiled=0,
                seconds=0.0,
                warnings=prepared.warnings,
            )
        if not plan.up_to_date:
            run = make.run(prepared.command, build_log, progress, planned=len(plan.units))
    else:  # from scratch: everything compiles, no dry run needed
        run = make.run(prepared.command, build_log, progress)
        values = run.values
        inputs = _inputs_fingerprint(prepared, values)
    elf = Path(values["elf"])
    usage = (run and run.usage) or _stored_usage(prepared, elf)
    if usage is None:  # an ELF linked outside wftool: relink once to learn its memory use
        elf.unlink(missing_ok=True)
        usage = make.run(prepared.command, build_log, progress).usage
    _store_usage(prepared, elf, usage)
    _stamp(prepared).write_text(_revision_stamp(prepared))
    published = _publish(prepared, values, inputs, usage, manifest_path, previous)
    published = dataclasses.replace(published, build_seconds=round(time.monotonic() - started, 2))
    published.write()
    return BuildResult(
        target=prepared.target,
        manifest=published,
        up_to_date=False,
        compiled=run.compiled if run else 0,
        seconds=published.build_seconds or 0.0,
        warnings=prepared.warnings,
    )


def prepare(
    project: Project, target_name: str, options: BuildOptions, log: Log = quiet
) -> Prepared:
    """Everything before make: tree, patches, toolchain, make variables."""
    target = resolve_target(project, target_name)
    for define in options.flags.defines:
        if not _DEFINE.match(define):
            raise UsageError(f"--define {define!r}: expected NAME or NAME=VALUE (no spaces/quotes)")
    tree.ensure_tree(project, target, allow_dirty=options.clean)
    patches.apply(project, force=options.clean, override="pass --clean")
    # Betaflight's make insists on CONFIG_DIR/configs/, even for SITL (git keeps no empty dir).
    (project.config_dir / "configs").mkdir(parents=True, exist_ok=True)
    warnings = []
    compiler = find_toolchain(project, target, options)
    if not compiler.matches:
        warnings.append(
            f"{compiler.gcc} is gcc {compiler.version}, the Betaflight tree asks for "
            f"{compiler.required}; building anyway (--strict-toolchain refuses)"
        )
        log(f"warning: {warnings[-1]}")
    variables = make_variables(target, project.config_dir, compiler, options.flags)
    # The object directory is per compiler and flags. Not per board config hash: make's
    # dependency files already recompile what includes config.h (and version.o is handled).
    compile_settings = {k: v for k, v in variables.items() if k != "CONFIG_REVISION_DEFINE"}
    key = hashlib.sha256(
        json.dumps([compile_settings, str(compiler.gcc), compiler.version]).encode()
    ).hexdigest()[:12]
    object_dir = project.build_dir / ".obj" / f"{target.name}-{key}"
    variables |= make.object_dir_variables(project.tree, object_dir)
    env = {"CCACHE_BASEDIR": str(project.root), "CCACHE_NOHASHDIR": "true", **CCACHE_DIRECT}
    if not options.ccache:
        env["CCACHE_DISABLE"] = "1"
    command = make.MakeCommand(
        tree=project.tree,
        variables=variables,
        jobs=options.jobs or os.cpu_count() or 1,
        hook=object_dir / "wftool.mk",
        env=env,
    )
    make.write_hook(command.hook)
    return Prepared(project, target, compiler, command, object_dir, options.flags, warnings)


CCACHE_DIRECT = {"CCACHE_SLOPPINESS": "time_macros"}
"""ccache hashes a unit's sources (direct mode) instead of preprocessing it, also where the
token __TIME__ appears: the STM32 HAL headers name macro parameters so, and a board build then
preprocessed every unit for a hit (~60 s of CPU, not ~25). version.c, which expands __DATE__
and __TIME__, is compiled without it (make.HOOK_MAKEFILE)."""

OFFLINE = {"AUTOHYDRATE_SUBMODULES": "", "AUTOHYDRATE_STAMPS": ""}
"""Betaflight 2026.6 would clone the submodules it hydrates (src/config, libcanard) from
GitHub for a build: wftool's boards are in targets/, and builds stay offline (harmless
before 2026.6)."""


def make_variables(
    target: Target, config_dir: Path, compiler: Toolchain, flags: BuildFlags
) -> dict[str, str]:
    """The make variables of a build of TARGET from a Betaflight tree (but where its objects
    go): the target, the board configs, the compiler, the flags."""
    variables = {
        **target.make_vars,
        "CONFIG_DIR": str(config_dir),
        # Betaflight checks the arm-none-eabi-gcc on PATH; these make it check ours instead,
        # and let SITL (host gcc) build without any ARM compiler installed.
        "GCC_VERSION": compiler.version,
        "GCC_REQUIRED_VERSION": compiler.version,
        **OFFLINE,
    }
    if not target.is_sitl:
        variables["ARM_SDK_PREFIX"] = compiler.prefix
        # Betaflight would embed the wftool checkout's git HEAD; the board file's hash is
        # what identifies the board definition, and keeps builds reproducible across commits.
        variables["CONFIG_REVISION_DEFINE"] = (
            f"-D'__CONFIG_REVISION__=\"{_board_config_sha256(target)[:7]}\"'"
        )
    defines = flags.compiler_defines() + [f"-D{d}" for d in target.defines]
    if defines:
        variables["EXTRA_FLAGS"] = " ".join(defines)
    if flags.debug:
        variables["DEBUG"] = "GDB"
    return variables


def find_toolchain(project: Project, target: Target, options: BuildOptions) -> Toolchain:
    """The host gcc for SITL; otherwise arm-none-eabi-gcc checked against the tree's version."""
    if target.is_sitl:
        return toolchain.host_toolchain()
    required, installed = toolchain.arm_requirement(project.tree)
    return toolchain.find_arm_toolchain(
        required,
        explicit=options.toolchain_dir,
        strict=options.strict_toolchain,
        installed=installed,
    )


def install_toolchain(
    project: Project | None,
    *,
    url: str | None = None,
    sha256: str | None = None,
    progress: Progress | None = None,
) -> Path:
    """Install the ARM toolchain the pinned tree names (fetching the tree if needed).

    URL replaces the tree's download address (a lab mirror); the file is still checked
    against the SHA-256 pinned for its name, or SHA256.
    """
    if sha256 is not None:
        sha256 = toolchain.parse_sha256(sha256)  # bad input is refused before any fetch
    if url is not None:
        release = toolchain.SdkRelease(url, None)
    else:
        if project is None:
            raise UsageError("without --url, the wftool project is needed to read mk/tools.mk")
        pin = tree.pinned_commit(project)
        if not tree.is_checked_out(project):
            tree.fetch_tree(project, pin, resolve_target(project, "sitl"))
        release = toolchain.sdk_release(tree.read_at(project, pin, "mk/tools.mk"))
    return toolchain.install(release, sha256=sha256, progress=progress)


def _board_config_sha256(target: Target) -> str:
    assert target.config_header is not None
    return file_sha256(target.config_header)


def _invalidate_stale_revision(prepared: Prepared) -> None:
    """Recompile build/version.c when the embedded revisions change.

    Betaflight's make rebuilds version.o only when a source file is newer; a new commit with
    the same files (or a new board config hash) would otherwise keep the old revision.
    """
    stamp = _stamp(prepared)
    if not stamp.exists() or stamp.read_text() != _revision_stamp(prepared):
        for version_object in prepared.object_dir.glob("*/build/version.o"):
            version_object.unlink()


def _stored_usage(prepared: Prepared, elf: Path) -> make.Usage | None:
    """The memory use recorded when ELF was linked, if ELF is still that file."""
    try:
        stored = json.loads((prepared.object_dir / ".wftool-usage.json").read_text())
        if stored["elf_sha256"] == file_sha256(elf):
            return make.Usage(**stored["usage"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def _store_usage(prepared: Prepared, elf: Path, usage: make.Usage | None) -> None:
    """Remember the link's memory use: a later build from the same objects does not relink."""
    if usage is not None:
        record = {"elf_sha256": file_sha256(elf), "usage": dataclasses.asdict(usage)}
        (prepared.object_dir / ".wftool-usage.json").write_text(json.dumps(record))


def _stamp(prepared: Prepared) -> Path:
    """Written when a build in the object directory finishes: the revisions it embedded."""
    return prepared.object_dir / ".wftool-revision"


def _revision_stamp(prepared: Prepared) -> str:
    config_revision = prepared.command.variables.get("CONFIG_REVISION_DEFINE", "")
    return f"{tree.head(prepared.project)} {config_revision}"


def _inputs_fingerprint(prepared: Prepared, values: dict[str, str]) -> str:
    """A hash of everything that determines the outputs, to tell a no-op from a rebuild."""
    inputs = {
        "head": tree.head(prepared.project),
        "revision": values.get("revision"),
        "variables": dict(prepared.command.variables),
        "toolchain": [str(prepared.toolchain.gcc), prepared.toolchain.version],
        "board_config": None if prepared.target.is_sitl else _board_config_sha256(prepared.target),
    }
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()


def _artifacts_intact(previous: Manifest) -> bool:
    """Whether every file the manifest lists is beside it with the recorded hash."""
    hashes = previous.artifact_sha256
    return bool(hashes) and all(
        (path := previous.artifact(kind)) is not None
        and path.is_file()
        and file_sha256(path) == digest
        for kind, digest in hashes.items()
    )


def _publish(
    prepared: Prepared,
    values: dict[str, str],
    inputs: str,
    usage: make.Usage | None,
    manifest_path: Path,
    previous: Manifest | None,
) -> Manifest:
    """Copy the outputs beside MANIFEST_PATH and return the manifest describing them."""
    out_dir = manifest_path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in (previous.artifacts if previous else {}).values():
        (out_dir / old).unlink(missing_ok=True)
    kinds = ("exe", "elf") if values.get("output") == "exe" else ("hex", "bin", "elf")
    artifacts, hashes = {}, {}
    for kind in kinds:
        source = Path(values[kind])
        shutil.copy2(source, out_dir / source.name)
        artifacts[kind] = source.name
        hashes[kind] = file_sha256(out_dir / source.name)
    target, compiler = prepared.target, prepared.toolchain
    series = patches.series(prepared.project)
    return Manifest(
        path=manifest_path,
        target=target.name,
        board=target.board,
        mcu=target.mcu,
        betaflight_commit=tree.pinned_commit(prepared.project),
        betaflight_head=tree.head(prepared.project),
        betaflight_version=values.get("version"),
        git_revision=values.get("revision", ""),
        patch_series_sha256=patches.series_sha256(series),
        patches=[{"name": patch.name, "sha256": patch.sha256} for patch in series],
        board_config_sha256=None if target.is_sitl else _board_config_sha256(target),
        toolchain={
            "path": str(compiler.gcc),
            "version": compiler.version,
            "required": compiler.required,
            "strict": compiler.strict,
        },
        flags=prepared.flags,
        usage=usage,
        build_seconds=None,
        built_at=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        artifacts=artifacts,
        artifact_sha256=hashes,
        inputs_sha256=inputs,
    )
