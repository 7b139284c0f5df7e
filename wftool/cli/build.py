"""Commands: building the firmware (build, patches, toolchain)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table
from rich.text import Text

from wftool.cli.progress import BYTES, UNITS, ProgressBars
from wftool.display import printable, shown
from wftool.errors import BuildError, PatchError, UsageError
from wftool.firmware import (
    BuildFlags,
    BuildOptions,
    BuildResult,
    build,
    builder,
    find_project,
    patches,
    tree,
)
from wftool.firmware.project import PROJECT_ENV, Project, exclusive
from wftool.firmware.targets import resolve_target
from wftool.fsp.schedule import RATE_HZ_MAX, RATE_HZ_MIN

# Piped output (CI logs, scripts) gets room for full paths instead of 80 folded columns.
out = Console(highlight=False, width=None if sys.stdout.isatty() else 200)
err = Console(stderr=True, highlight=False)

project_option = click.option(
    "--project",
    "project_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help=f"The wftool checkout (default: ${PROJECT_ENV}, else the one around the cwd).",
)


def project_from(project_dir: Path | None) -> Project:
    """The project --project names, or the one found from the environment/cwd."""
    return find_project(project_dir)


def note(message: str) -> None:
    """The API's news (`Log`) on stderr; warnings in yellow."""
    err.print(shown(message, "yellow" if message.startswith("warning:") else ""), soft_wrap=True)


def locked(project: Project) -> AbstractContextManager[None]:
    """The checkout's lock, saying so when another wftool run holds it."""
    return exclusive(project, lambda: note("waiting for another wftool run"))


def build_with_progress(
    project: Project, target: str, options: BuildOptions | None = None
) -> BuildResult:
    """`build()` with make's progress drawn on stderr."""
    with ProgressBars(err, UNITS) as bars:
        return build(project, target, options, progress=bars, log=note)


def build_options(function: Callable[..., Any]) -> Callable[..., Any]:
    """The options of `wftool build`, shared with `wftool bench build`."""
    options = [
        click.option(
            "--fsp-rate",
            type=click.IntRange(RATE_HZ_MIN, RATE_HZ_MAX),
            metavar="HZ",
            help="Default of the firmware's fsp_rate_hz setting (-DFSP_RATE_HZ_DEFAULT).",
        ),
        click.option(
            "--mavlink-tunnel",
            is_flag=True,
            help="Build with the FSP MAVLink tunnel (-DUSE_FSP_MAVLINK_TUNNEL).",
        ),
        click.option(
            "--define",
            "defines",
            multiple=True,
            metavar="NAME[=VALUE]",
            help="Extra -D for the compiler; repeatable.",
        ),
        click.option("--debug", is_flag=True, help="Debug build (Betaflight's DEBUG=GDB: -Og)."),
        click.option("-j", "--jobs", type=click.IntRange(1), help="Parallel jobs (default: CPUs)."),
        click.option(
            "--toolchain",
            "toolchain_dir",
            type=click.Path(file_okay=False, exists=True, path_type=Path),
            help="Directory of arm-none-eabi-gcc (or its parent with bin/).",
        ),
        click.option(
            "--strict-toolchain",
            is_flag=True,
            help="Fail instead of warning when gcc is not the version Betaflight names.",
        ),
        click.option("--no-ccache", is_flag=True, help="Compile without ccache."),
        project_option,
    ]
    for option in reversed(options):
        function = option(function)
    return function


def options_from(
    fsp_rate: int | None,
    mavlink_tunnel: bool,
    defines: tuple[str, ...],
    debug: bool,
    jobs: int | None,
    toolchain_dir: Path | None,
    strict_toolchain: bool,
    no_ccache: bool,
    **extra: Any,
) -> BuildOptions:
    """BuildOptions from the values of `build_options`."""
    return BuildOptions(
        flags=BuildFlags(fsp_rate, mavlink_tunnel, defines, debug),
        jobs=jobs,
        toolchain_dir=toolchain_dir,
        strict_toolchain=strict_toolchain,
        ccache=not no_ccache,
        **extra,
    )


@click.command("build")
@click.argument("target")
@build_options
@click.option(
    "--clean",
    is_flag=True,
    help="Discard uncommitted changes and unexported commits in betaflight/.",
)
@click.option("--rebuild", is_flag=True, help="Recompile everything for this configuration.")
def build_command(
    target: str, project_dir: Path | None, clean: bool, rebuild: bool, **options: Any
) -> None:
    """Build firmware for TARGET (sitl, speedybeef7v3, any board in targets/configs/).

    Fetches the pinned Betaflight tree if needed, applies patches/, compiles, and writes
    build/<target>/ with the firmware and manifest.json.
    """
    result = build_with_progress(
        project_from(project_dir), target, options_from(clean=clean, rebuild=rebuild, **options)
    )
    print_summary(result)


def print_summary(result: BuildResult) -> None:
    """The table at the end of a build: target, size, flash %, RAM %, path."""
    manifest = result.manifest
    usage = manifest.usage
    table = Table(box=None, pad_edge=False)
    for column in ("target", "size", "flash", "RAM"):
        table.add_column(column, justify="left" if column == "target" else "right")
    table.add_column("firmware", overflow="fold")
    sized = manifest.artifact("bin") or manifest.artifact("exe") or manifest.artifact("elf")
    assert sized is not None
    table.add_row(
        shown(manifest.target),
        f"{sized.stat().st_size / 1024:.1f} KiB",
        _percent(usage.flash_bytes, usage.flash_total) if usage else "-",
        _percent(usage.ram_bytes, usage.ram_total) if usage else "-",
        shown(_shown_path(result.firmware)),
    )
    state = (
        "up to date"
        if result.up_to_date
        else (f"built in {result.seconds:.1f} s, {result.compiled} units compiled")
    )
    out.print(shown(f"{manifest.target}: {state} (git revision {manifest.git_revision})"))
    out.print(table)


def _percent(used: int | None, total: int | None) -> str:
    if used is None:
        return "-"
    return f"{100 * used / total:.1f} %" if total else f"{used / 1024:.0f} KiB"


def _shown_path(path: Path) -> str:
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


@click.group("patches")
def patches_group() -> None:
    """The Betaflight patch series in patches/ (status, apply, reset, export, test, check)."""


@patches_group.command("status")
@project_option
def patches_status(project_dir: Path | None) -> None:
    """Show the pin, HEAD, and which patches betaflight/ contains."""
    project = project_from(project_dir)
    current = patches.status(project)
    out.print(shown(f"pin       {current.pin}"))
    out.print(shown(f"HEAD      {current.head}"))
    out.print(f"state     {current.state}" + (" (uncommitted changes)" if current.dirty else ""))
    for patch, applied in zip(current.patches, current.applied, strict=True):
        state = "applied" if applied else "missing"
        out.print(shown(f"  {state:8} {patch.name}  {patch.sha256[:12]}"))
    if not current.patches:
        out.print("  (patches/ holds no *.patch files)")
    for path in current.dirty:
        out.print(shown(f"  dirty    {path}"))
    if current.problem:
        raise PatchError(f"the series does not apply to the pin: {current.problem}")


@patches_group.command("apply")
@click.option(
    "--target",
    default="sitl",
    show_default=True,
    help="Target whose files to check out when betaflight/ must be fetched first.",
)
@click.option("--force", is_flag=True, help="Discard uncommitted changes and unexported commits.")
@project_option
def patches_apply(target: str, force: bool, project_dir: Path | None) -> None:
    """Put betaflight/ at the pin plus the series (a no-op when it already is)."""
    project = project_from(project_dir)
    with locked(project):
        tree.ensure_tree(project, resolve_target(project, target), allow_dirty=True)
        changed = patches.apply(project, force=force)
    count = len(patches.series(project))
    out.print(
        f"{'applied' if changed else 'already applied:'} {count} patch(es) "
        f"-> {tree.head(project)[:12]}"
    )


@patches_group.command("reset")
@click.option("--force", is_flag=True, help="Discard uncommitted changes and unexported commits.")
@project_option
def patches_reset(force: bool, project_dir: Path | None) -> None:
    """Return betaflight/ to the pristine pinned commit."""
    project = project_from(project_dir)
    with locked(project):
        changed = patches.reset(project, force=force)
    out.print(f"{'reset to' if changed else 'already at'} the pin {tree.head(project)[:12]}")


@patches_group.command("export")
@project_option
def patches_export(project_dir: Path | None) -> None:
    """Rewrite patches/ from the commits on top of the pin in betaflight/."""
    project = project_from(project_dir)
    with locked(project):
        names = patches.export(project)
    out.print(f"exported {len(names)} patch(es) to patches/")
    for name in names:
        out.print(shown(f"  {name}"))


@patches_group.command("test")
@click.argument("names", nargs=-1)
@click.option("--all", "everything", is_flag=True, help="All of Betaflight's unit tests.")
@project_option
def patches_test(names: tuple[str, ...], everything: bool, project_dir: Path | None) -> None:
    """Run Betaflight unit tests on the patched tree (default: the ones the series adds)."""
    from wftool.firmware.unittests import run_unit_tests

    if everything and names:
        raise UsageError("--all runs every unit test: leave out NAMES")
    project = project_from(project_dir)
    with locked(project):
        runs = run_unit_tests(project, list(names) or None, everything=everything)
    for run in runs:
        if run.not_run:
            reason = shown(f"{run.name}: {run.not_run}")
            out.print(Text.assemble("  ", ("n/a ", "yellow"), "  ", reason))
            continue
        mark = ("pass", "green") if run.passed else ("FAIL", "red")
        out.print(Text.assemble("  ", mark, "  ", shown(run.name)))
        if not run.passed:
            for line in run.output[-3000:].splitlines():
                out.print(shown(line))
    failed = [run.name for run in runs if not run.passed and not run.not_run]
    not_run = [run.name for run in runs if run.not_run]
    if failed:
        raise BuildError(f"{len(failed)} of {len(runs)} unit test(s) failed: {', '.join(failed)}")
    if not_run:
        raise BuildError(
            f"{len(runs) - len(not_run)} unit test(s) passed, {len(not_run)} could not be "
            f"built: {', '.join(not_run)} (a submodule they need could not be fetched)"
        )
    out.print(f"{len(runs)} unit test(s) passed")


@patches_group.command("check")
@click.option(
    "--against", "ref", required=True, metavar="REF",
    help="A tag (2026.6.1), a branch (master) or a commit id of Betaflight's repository.",
)  # fmt: skip
@click.option(
    "--workdir", type=click.Path(file_okay=False, path_type=Path),
    help="Keep the scratch tree here (an empty or new directory) [default: a temporary one].",
)  # fmt: skip
@click.option("-j", "--jobs", type=click.IntRange(1), default=2, show_default=True)
@click.option("--apply-only", is_flag=True, help="Only apply: no SITL build, no unit tests.")
@click.option("--markdown", is_flag=True, help="Print the table as Markdown (for docs).")
@project_option
def patches_check(
    ref: str,
    workdir: Path | None,
    jobs: int,
    apply_only: bool,
    markdown: bool,
    project_dir: Path | None,
) -> None:
    """The upstream canary: apply the series to REF in a scratch tree (never betaflight/),
    patch by patch, build the SITL and run each patch's unit tests; a table per patch.
    Exit 1 unless every patch applies, builds and passes."""
    from wftool.firmware.canary import Applied, check_against

    project = project_from(project_dir)
    report = check_against(project, ref, workdir=workdir, jobs=jobs, build=not apply_only, log=note)
    rows = []
    for check in report.checks:
        applied = check.applied.value
        if check.applied is Applied.CONFLICT and not check.taken:
            applied += ", left out"
        conflicts = ", ".join(check.conflicts) if check.applied is Applied.CONFLICT else ""
        built = {None: "—", True: "yes", False: "no"}[check.built]
        passed = sum(run.passed for run in check.tests)
        failed = [run.name.removeprefix("test_") for run in check.tests if not run.passed]
        not_run = [run.name.removeprefix("test_") for run in check.tests if run.not_run]
        tests = f"{passed}/{len(check.tests)}" if check.tests else "—"
        if failed_run := [name for name in failed if name not in not_run]:
            tests += f" ({', '.join(failed_run)} fail)"
        if not_run:
            tests += f" ({', '.join(not_run)} not built: a submodule it needs was not fetched)"
        rows.append((check.name, applied, conflicts, built, tests))
    title = f"the series on {ref} ({report.commit[:9]}, Betaflight {report.version})"
    header = ("patch", "applies", "conflicts (files)", "SITL builds", "its unit tests")
    if markdown:  # unwrapped, one line a row
        click.echo(f"{title}:\n")
        click.echo("| " + " | ".join(header) + " |")
        click.echo("|" + " --- |" * len(header))
        for row in rows:
            click.echo(printable("| " + " | ".join(cell or " " for cell in row) + " |"))
    else:
        table = Table(title=title, title_justify="left")
        for column in header:
            table.add_column(column)
        for row in rows:
            table.add_row(*(shown(cell) for cell in row))
        out.print(table)
    out.print(
        "A conflicting patch is taken with the series' version of the files it conflicts in "
        "(so the patches after it meet what they were written on); its build and tests say "
        "whether that holds."
    )
    shown_error = None
    for check in report.checks:
        if check.build_error and check.build_error != shown_error:
            out.print(shown(f"from {check.name} on, the SITL does not build: {check.build_error}"))
            shown_error = check.build_error
    if not report.ok:
        raise BuildError(f"the series does not carry over to {ref} as it is (table above)")


@click.group("toolchain")
def toolchain_group() -> None:
    """The ARM GNU toolchain (install, show)."""


@toolchain_group.command("install")
@click.option("--sha256", metavar="HEX", help="Expected SHA-256 when wftool pins none.")
@click.option("--url", help="Download from here instead (a mirror of the same archive).")
@project_option
def toolchain_install(sha256: str | None, url: str | None, project_dir: Path | None) -> None:
    """Download, verify and unpack the toolchain release the pinned Betaflight names."""
    project = None if url else project_from(project_dir)
    with ProgressBars(err, BYTES) as bars:
        directory = builder.install_toolchain(project, url=url, sha256=sha256, progress=bars)
    out.print(shown(f"toolchain ready: {directory}"))


@toolchain_group.command("show")
@click.argument("target", default="speedybeef7v3")
@click.option(
    "--toolchain", "toolchain_dir", type=click.Path(file_okay=False, exists=True, path_type=Path)
)
@project_option
def toolchain_show(target: str, toolchain_dir: Path | None, project_dir: Path | None) -> None:
    """Show which compiler a build of TARGET would use, and the version it should be."""
    project = project_from(project_dir)
    resolved = resolve_target(project, target)
    tree.ensure_tree(project, resolved, allow_dirty=True)  # only reads mk/tools.mk
    compiler = builder.find_toolchain(project, resolved, BuildOptions(toolchain_dir=toolchain_dir))
    verdict = "ok" if compiler.matches else f"MISMATCH (tree asks for {compiler.required})"
    out.print(shown(f"{compiler.gcc}  gcc {compiler.version}  {verdict}"))


COMMANDS: list[click.Command] = [build_command, patches_group, toolchain_group]
