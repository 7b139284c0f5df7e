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
from typing import Any

from rich.console import Console

from wftool.errors import ToolchainError, UsageError
from wftool.firmware import make, manifest, patches, toolchain, tree
from wftool.firmware.manifest import BuildFlags
from wftool.firmware.project import Project, exclusive
from wftool.firmware.targets import Target, resolve_target
from wftool.firmware.toolchain import Toolchain

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
    manifest_path: Path
    manifest: dict[str, Any]
    up_to_date: bool
    """Nothing was compiled or copied: the outputs already matched the inputs."""
    compiled: int
    seconds: float
    warnings: list[str]

    @property
    def out_dir(self) -> Path:
        """build/<target>/."""
        return self.manifest_path.parent

    @property
    def firmware(self) -> Path:
        """The file to flash (.hex) or to run (SITL)."""
        artifacts = self.manifest["artifacts"]
        return self.out_dir / artifacts.get("hex", artifacts.get("exe", artifacts["elf"]))


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
    console: Console | None = None,
) -> BuildResult:
    """Build TARGET_NAME; CONSOLE (stderr) gets the progress bar and warnings."""
    on_wait = None if console is None else lambda: console.print("waiting for another wftool run")
    with exclusive(project, on_wait):
        return _build(project, target_name, options or BuildOptions(), console)


def _build(
    project: Project, target_name: str, options: BuildOptions, console: Console | None
) -> BuildResult:
    started = time.monotonic()
    prepared = prepare(project, target_name, options, console)
    if options.rebuild:
        shutil.rmtree(prepared.object_dir, ignore_errors=True)
        make.write_hook(prepared.command.hook)
    _invalidate_stale_revision(prepared)
    out_dir = project.build_dir / prepared.target.name
    manifest_path = out_dir / manifest.FILE_NAME
    previous = manifest.read(manifest_path)
    log = out_dir / "build.log"
    run = None
    if _stamp(prepared).exists():  # objects of a finished build: find what is out of date
        plan = make.plan(prepared.command)
        values = plan.values
        inputs = _inputs_fingerprint(prepared, values)
        same_inputs = previous is not None and previous.get("inputs_sha256") == inputs
        if plan.up_to_date and same_inputs and _artifacts_intact(out_dir, previous):
            return BuildResult(
                target=prepared.target,
                manifest_path=manifest_path,
                manifest=previous,
                up_to_date=True,
                compiled=0,
                seconds=0.0,
                warnings=prepared.warnings,
            )
        if not plan.up_to_date:
            run = make.run(prepared.command, log, console, planned=len(plan.units))
    else:  # from scratch: everything compiles, no dry run needed
        run = make.run(prepared.command, log, console)
        values = run.values
        inputs = _inputs_fingerprint(prepared, values)
    elf = Path(values["elf"])
    usage = (run and run.usage) or _stored_usage(prepared, elf)
    if usage is None:  # an ELF linked outside wftool: relink once to learn its memory use
        elf.unlink(missing_ok=True)
        usage = make.run(prepared.command, log, console).usage
    _store_usage(prepared, elf, usage)
    _stamp(prepared).write_text(_revision_stamp(prepared))
    data = _publish(prepared, values, inputs, usage, out_dir, previous)
    data["build_seconds"] = round(time.monotonic() - started, 2)
    manifest.write(manifest_path, data)
    return BuildResult(
        target=prepared.target,
        manifest_path=manifest_path,
        manifest=data,
        up_to_date=False,
        compiled=run.compiled if run else 0,
        seconds=data["build_seconds"],
        warnings=prepared.warnings,
    )


def prepare(
    project: Project, target_name: str, options: BuildOptions, console: Console | None
) -> Prepared:
    """Everything before make: tree, patches, toolchain, make variables."""
    target = resolve_target(project, target_name)
    for define in options.flags.defines:
        if not _DEFINE.match(define):
            raise UsageError(f"--define {define!r}: expected NAME or NAME=VALUE (no spaces/quotes)")
    tree.ensure_tree(project, target, clean=options.clean)
    patches.apply(project, force=options.clean)
    # Betaflight's make insists on CONFIG_DIR/configs/, even for SITL (git keeps no empty dir).
    (project.config_dir / "configs").mkdir(parents=True, exist_ok=True)
    warnings = []
    compiler = find_toolchain(project, target, options)
    if not compiler.matches:
        warnings.append(
            f"{compiler.gcc} is gcc {compiler.version}, the Betaflight tree asks for "
            f"{compiler.required}; building anyway (--strict-toolchain refuses)"
        )
        if console is not None:
            console.print(f"[yellow]warning:[/] {warnings[-1]}", soft_wrap=True)
    variables = {
        **target.make_vars,
        "CONFIG_DIR": str(project.config_dir),
        # Betaflight checks the arm-none-eabi-gcc on PATH; these make it check ours instead,
        # and let SITL (host gcc) build without any ARM compiler installed.
        "GCC_VERSION": compiler.version,
        "GCC_REQUIRED_VERSION": compiler.version,
    }
    if not target.is_sitl:
        variables["ARM_SDK_PREFIX"] = compiler.prefix
        # Betaflight would embed the wftool checkout's git HEAD; the board file's hash is
        # what identifies the board definition, and keeps builds reproducible across commits.
        variables["CONFIG_REVISION_DEFINE"] = (
            f"-D'__CONFIG_REVISION__=\"{_board_config_sha256(target)[:7]}\"'"
        )
    defines = options.flags.compiler_defines() + [f"-D{d}" for d in target.defines]
    if defines:
        variables["EXTRA_FLAGS"] = " ".join(defines)
    if options.flags.debug:
        variables["DEBUG"] = "GDB"
    # The object directory is per compiler and flags. Not per board config hash: make's
    # dependency files already recompile what includes config.h (and version.o is handled).
    compile_settings = {k: v for k, v in variables.items() if k != "CONFIG_REVISION_DEFINE"}
    key = hashlib.sha256(
        json.dumps([compile_settings, str(compiler.gcc), compiler.version]).encode()
    ).hexdigest()[:12]
    object_dir = project.build_dir / ".obj" / f"{target.name}-{key}"
    variables |= {"OBJECT_DIR": str(object_dir), "BIN_DIR": str(object_dir)}
    env = {"CCACHE_BASEDIR": str(project.root), "CCACHE_NOHASHDIR": "true"}
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


def find_toolchain(project: Project, target: Target, options: BuildOptions) -> Toolchain:
    """The host gcc for SITL; otherwise arm-none-eabi-gcc checked against the tree's version."""
    if target.is_sitl:
        return toolchain.host_toolchain()
    tools_mk = (project.tree / "mk" / "tools.mk").read_text()
    try:
        installed = toolchain.sdk_release(tools_mk).directory_name
    except ToolchainError:  # no ARM release for this host; PATH or --toolchain must do
        installed = None
    return toolchain.find_arm_toolchain(
        toolchain.required_version(tools_mk),
        explicit=options.toolchain_dir,
        strict=options.strict_toolchain,
        installed=installed,
    )


def install_toolchain(
    project: Project | None,
    *,
    url: str | None = None,
    sha256: str | None = None,
    console: Console | None = None,
) -> Path:
    """Install the ARM toolchain the pinned tree names (fetching the tree if needed).

    URL replaces the tree's download address (a lab mirror); the file is still checked
    against the SHA-256 pinned for its name, or SHA256.
    """
    if url is not None:
        release = toolchain.SdkRelease(url, None)
    else:
        if project is None:
            raise UsageError("without --url, the wftool project is needed to read mk/tools.mk")
        pin = tree.pinned_commit(project)
        if not tree.is_checked_out(project):
            tree.fetch_tree(project, pin, resolve_target(project, "sitl"))
        release = toolchain.sdk_release(tree.read_at(project, pin, "mk/tools.mk"))
    return toolchain.install(release, sha256=sha256, console=console)


def _board_config_sha256(target: Target) -> str:
    assert target.config_header is not None
    return manifest.file_sha256(target.config_header)


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
        if stored["elf_sha256"] == manifest.file_sha256(elf):
            return make.Usage(**stored["usage"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def _store_usage(prepared: Prepared, elf: Path, usage: make.Usage | None) -> None:
    """Remember the link's memory use: a later build from the same objects does not relink."""
    if usage is not None:
        record = {"elf_sha256": manifest.file_sha256(elf), "usage": dataclasses.asdict(usage)}
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


def _artifacts_intact(out_dir: Path, data: dict[str, Any]) -> bool:
    """Whether every file the manifest lists is in OUT_DIR with the recorded hash."""
    hashes = data.get("artifact_sha256", {})
    return bool(hashes) and all(
        (out_dir / data["artifacts"][kind]).is_file()
        and manifest.file_sha256(out_dir / data["artifacts"][kind]) == digest
        for kind, digest in hashes.items()
    )


def _publish(
    prepared: Prepared,
    values: dict[str, str],
    inputs: str,
    usage: make.Usage | None,
    out_dir: Path,
    previous: dict[str, Any] | None,
) -> dict[str, Any]:
    """Copy the outputs into OUT_DIR and return the manifest describing them."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in (previous or {}).get("artifacts", {}).values():
        (out_dir / old).unlink(missing_ok=True)
    kinds = ("exe", "elf") if values.get("output") == "exe" else ("hex", "bin", "elf")
    artifacts, hashes = {}, {}
    for kind in kinds:
        source = Path(values[kind])
        shutil.copy2(source, out_dir / source.name)
        artifacts[kind] = source.name
        hashes[kind] = manifest.file_sha256(out_dir / source.name)
    target, compiler = prepared.target, prepared.toolchain
    series = patches.series(prepared.project)
    revision = values.get("revision", "")
    return {
        "schema": manifest.SCHEMA,
        "target": target.name,
        "board": target.board,
        "mcu": target.mcu,
        "betaflight_commit": tree.pinned_commit(prepared.project),
        "betaflight_head": tree.head(prepared.project),
        "betaflight_version": values.get("version"),
        "git_revision": revision,
        "git_revision_msp": revision[: manifest.MSP_REVISION_LENGTH],
        "patch_series_sha256": patches.series_sha256(series),
        "patches": [{"name": patch.name, "sha256": patch.sha256} for patch in series],
        "board_config_sha256": None if target.is_sitl else _board_config_sha256(target),
        "toolchain": {
            "path": str(compiler.gcc),
            "version": compiler.version,
            "required": compiler.required,
            "strict": compiler.strict,
        },
        "flags": prepared.flags.to_json(),
        "usage": None if usage is None else dataclasses.asdict(usage),
        "build_seconds": None,
        "built_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "artifacts": artifacts,
        "artifact_sha256": hashes,
        "inputs_sha256": inputs,
    }
