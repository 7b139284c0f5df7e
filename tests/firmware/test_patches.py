"""The patch series on a small real git repository: apply, no-op, conflict, export."""

from __future__ import annotations

import shutil

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
    with pytest.raises(SystemExit):
        main(["patches", "status", "--project", str(fixture_project.root)])
    status = capsys.readouterr().out
    assert "state     pristine" in status
    assert "does not apply: 0002-a.patch" in status


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
