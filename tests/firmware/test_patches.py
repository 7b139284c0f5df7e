"""The patch series on a small real git repository: apply, no-op, conflict, export."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from wftool.cli import main
from wftool.errors import PatchError
from wftool.firmware import patches, tree
from wftool.firmware.project import Project

from .conftest import commit_all, run_git

A_PATCHED = "int a(void)\n{\n    return 10;\n}\n"
B_PATCHED = "int b(void)\n{\n    return 20;\n}\n"


def test_apply_commits_the_series_deterministically(fixture_project, make_patch, upstream):
    _, pin = upstream
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    make_patch(fixture_project, "0002-b.patch", {"src/main/b.c": B_PATCHED})

    assert patches.apply(fixture_project) is True

    work = fixture_project.tree
    assert (work / "src/main/a.c").read_text() == A_PATCHED
    assert (work / "src/main/b.c").read_text() == B_PATCHED
    head = tree.head(fixture_project)
    assert run_git(work, "rev-list", "--count", f"{pin}..HEAD") == "2"
    # committer = author, committer date = the patch's date: the same hash everywhere
    assert run_git(work, "log", "-1", "--format=%an|%cn|%ad|%cd", "--date=iso-strict") == (
        "Test Author|Test Author|2025-02-03T04:05:06+00:00|2025-02-03T04:05:06+00:00"
    )
    patches.reset(fixture_project)
    assert tree.head(fixture_project) == pin
    patches.apply(fixture_project)
    assert tree.head(fixture_project) == head
    assert patches.status(fixture_project).state == "applied"


def test_reapply_is_a_noop_that_touches_no_file(fixture_project, make_patch):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    patches.apply(fixture_project)
    patched = fixture_project.tree / "src/main/a.c"
    before = patched.stat().st_mtime_ns
    head = tree.head(fixture_project)

    assert patches.apply(fixture_project) is False

    assert tree.head(fixture_project) == head
    assert patched.stat().st_mtime_ns == before


def test_conflict_names_patch_and_file_and_leaves_the_pristine_pin(
    fixture_project, make_patch, upstream
):
    _, pin = upstream
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    # made against the pin, not on top of 0001: its context no longer matches
    make_patch(
        fixture_project,
        "0002-a-again.patch",
        {"src/main/a.c": "int a(void)\n{\n    return 99;\n}\n"},
        base=pin,
    )
    make_patch(fixture_project, "0003-b.patch", {"src/main/b.c": B_PATCHED})

    with pytest.raises(PatchError) as failure:
        patches.apply(fixture_project)

    message = str(failure.value)
    assert "0002-a-again.patch" in message
    assert "src/main/a.c" in message
    assert tree.head(fixture_project) == pin
    assert tree.dirty_paths(fixture_project) == []
    assert (fixture_project.tree / "src/main/a.c").read_text().endswith("return 1;\n}\n")
    assert not (fixture_project.tree / ".git" / "rebase-apply").exists()


def test_a_later_conflict_also_undoes_an_earlier_application(fixture_project, make_patch, upstream):
    _, pin = upstream
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    patches.apply(fixture_project)
    make_patch(fixture_project, "0002-b.patch", {"src/main/b.c": B_PATCHED}, base=pin)
    (fixture_project.patches_dir / "0002-b.patch").write_text(
        (fixture_project.patches_dir / "0002-b.patch").read_text().replace("return 2;", "return 3;")
    )

    with pytest.raises(PatchError, match=r"0002-b\.patch does not apply: src/main/b\.c"):
        patches.apply(fixture_project)

    assert tree.head(fixture_project) == pin


def test_dirty_tree_is_refused_and_force_discards(fixture_project, make_patch):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    (fixture_project.tree / "src/main/b.c").write_text("/* local edit */\n")
    (fixture_project.tree / "scratch.txt").write_text("untracked\n")

    with pytest.raises(PatchError, match="uncommitted changes"):
        patches.apply(fixture_project)
    assert (fixture_project.tree / "scratch.txt").exists()

    assert patches.apply(fixture_project, force=True) is True
    assert tree.dirty_paths(fixture_project) == []
    assert (fixture_project.tree / "src/main/a.c").read_text() == A_PATCHED


def test_unexported_commits_are_protected_until_exported(fixture_project, make_patch):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    patches.apply(fixture_project)
    (fixture_project.tree / "src/main/b.c").write_text(B_PATCHED)
    commit_all(fixture_project.tree, "Make b return 20\n\nA researcher's change.")

    assert patches.status(fixture_project).state == "modified"
    with pytest.raises(PatchError, match="patches export"):
        patches.apply(fixture_project)
    with pytest.raises(PatchError, match="patches export"):
        patches.reset(fixture_project)

    names = patches.export(fixture_project)

    assert names == ["0001-Change-0001-a.patch.patch", "0002-Make-b-return-20.patch"]
    assert sorted(path.name for path in fixture_project.patches_dir.glob("*.patch")) == names
    current = patches.status(fixture_project)
    assert current.state == "applied"
    assert current.applied == [True, True]
    assert (fixture_project.tree / "src/main/b.c").read_text() == B_PATCHED


def test_export_output_is_stable(fixture_project, make_patch):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    patches.apply(fixture_project)
    first = patches.export(fixture_project)
    contents = {name: (fixture_project.patches_dir / name).read_bytes() for name in first}

    second = patches.export(fixture_project)

    assert second == first
    for name in second:
        text = (fixture_project.patches_dir / name).read_bytes()
        assert text == contents[name]
        assert text.startswith(b"From 0000000000000000000000000000000000000000 ")
        assert b"Subject: [PATCH] " in text
        assert not text.rstrip().endswith(b"-- \n2.")  # no git version signature
    assert (fixture_project.patches_dir / "0001-a.patch").exists() is False


def test_same_series_gives_same_commit_in_another_clone(
    fixture_project, make_patch, tmp_path, upstream
):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    patches.apply(fixture_project)
    other = Project(tmp_path / "other")
    shutil.copytree(fixture_project.root, other.root, symlinks=True)
    patches.reset(other)
    shutil.rmtree(other.tree / ".git" / "refs" / "wftool", ignore_errors=True)

    patches.apply(other)

    assert tree.head(other) == tree.head(fixture_project)


def test_status_lists_each_patch(fixture_project, make_patch):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    current = patches.status(fixture_project)
    assert current.state == "pristine"
    assert [patch.name for patch in current.patches] == ["0001-a.patch"]
    assert current.applied == [False]
    assert len(patches.series_sha256(current.patches)) == 64


def test_cli_reports_a_conflict_in_one_line(fixture_project, make_patch, upstream, capsys):
    _, pin = upstream
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    make_patch(fixture_project, "0002-a.patch", {"src/main/a.c": "x\n"}, base=pin)

    with pytest.raises(SystemExit) as exit_info:
        main(["patches", "apply", "--project", str(fixture_project.root)])

    assert exit_info.value.code == 1
    error = capsys.readouterr().err.strip()
    assert "\n" not in error
    assert "0002-a.patch" in error and "src/main/a.c" in error
    assert "Traceback" not in error
    with pytest.raises(SystemExit) as status_exit:
        main(["patches", "status", "--project", str(fixture_project.root)])
    status = capsys.readouterr()
    assert "state     pristine" in status.out
    assert status_exit.value.code == 1  # the series does not apply: that is a failure
    assert status.err.startswith("error: the series does not apply to the pin: 0002-a.patch")
    assert status.err.count("\n") == 1


def test_cli_status_and_reset(fixture_project, make_patch, capsys):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    root = str(fixture_project.root)
    with pytest.raises(SystemExit) as exit_info:
        main(["patches", "apply", "--project", root])
    assert exit_info.value.code == 0
    with pytest.raises(SystemExit):
        main(["patches", "status", "--project", root])
    assert "state     applied" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["patches", "reset", "--project", root])
    assert "reset to the pin" in capsys.readouterr().out


def test_fixture_is_a_real_submodule_layout(fixture_project, upstream):
    _, pin = upstream
    assert tree.pinned_commit(fixture_project) == pin
    assert tree.is_checked_out(fixture_project)


LATIN1_C = "int a(void)\n{\n    return 10; /* M\xfcller */\n}\n".encode("latin-1")


def _latin1_patch(project: Project, scratch_parent, upstream) -> None:
    """0001-latin1.patch: a change whose text is Latin-1, not UTF-8 (byte 0xfc)."""
    repo, pin = upstream
    scratch = scratch_parent / "latin1-scratch"
    run_git(scratch_parent, "clone", "-q", str(repo), str(scratch))
    run_git(scratch, "checkout", "-q", "--detach", pin)
    (scratch / "src/main/a.c").write_bytes(LATIN1_C)
    commit_all(scratch, "Credit M\xfcller")
    patch = subprocess.run(
        ["git", "format-patch", "--stdout", "-1", "HEAD"], cwd=scratch, check=True,
        capture_output=True,
    ).stdout  # fmt: skip
    assert b"\xfc" in patch
    (project.patches_dir / "0001-latin1.patch").write_bytes(patch)


def test_a_patch_with_a_non_utf8_byte_is_applied_and_reported(
    fixture_project, upstream, tmp_path, capsys
):
    _latin1_patch(fixture_project, tmp_path, upstream)
    root = str(fixture_project.root)
    for args, expected in ((["status"], "missing  0001-latin1.patch"),
                           (["apply"], "applied 1 patch(es)"),
                           (["status"], "applied  0001-latin1.patch")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_info:
            main(["patches", *args, "--project", root])
        captured = capsys.readouterr()
        assert (exit_info.value.code, "Traceback" in captured.err) == (0, False), captured.err
        assert expected in captured.out
    assert (fixture_project.tree / "src/main/a.c").read_bytes() == LATIN1_C
    assert patches.export(fixture_project) == ["0001-Credit-M-ller.patch"]
    assert patches.status(fixture_project).state == "applied"


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exit_info:
        main(list(args))
    captured = capsys.readouterr()
    return int(exit_info.value.code or 0), captured.out, captured.err


def test_refusal_names_the_option_the_command_has(fixture_project, make_patch, capsys):
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    (fixture_project.tree / "src/main/b.c").write_text("/* local edit */\n")
    root = str(fixture_project.root)
    for command, option in ((["patches", "apply"], "--force"), (["patches", "reset"], "--force")):
        code, _, err = _cli(capsys, *command, "--project", root)
        assert code == 1
        assert f"or pass {option} to " in err and "--clean" not in err, err
    assert (fixture_project.tree / "src/main/b.c").read_text() == "/* local edit */\n"


def test_force_checks_the_series_applies_before_discarding_anything(
    fixture_project, make_patch, upstream, capsys
):
    _, pin = upstream
    make_patch(fixture_project, "0001-a.patch", {"src/main/a.c": A_PATCHED})
    make_patch(fixture_project, "0002-a.patch", {"src/main/a.c": "x\n"}, base=pin)  # conflicts
    (fixture_project.tree / "src/main/b.c").write_text("/* a day of work */\n")
    (fixture_project.tree / "notes.txt").write_text("untracked, too\n")

    code, _, err = _cli(
        capsys, "patches", "apply", "--force", "--project", str(fixture_project.root)
    )

    assert code == 1
    assert "0002-a.patch does not apply: src/main/a.c" in err
    assert "betaflight/ is left as it was, nothing discarded" in err
    assert (fixture_project.tree / "src/main/b.c").read_text() == "/* a day of work */\n"
    assert (fixture_project.tree / "notes.txt").exists()
    assert tree.head(fixture_project) == pin
