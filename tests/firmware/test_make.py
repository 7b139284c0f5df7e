"""The make driver with real make and the host gcc, on a Makefile shaped like Betaflight's."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from wftool.errors import BuildError
from wftool.firmware import make

pytestmark = pytest.mark.skipif(
    not (shutil.which("make") and shutil.which("gcc")), reason="needs make and gcc"
)

# The variables and messages wftool reads from Betaflight's Makefile, on two C files.
MAKEFILE = """\
TARGET_ELF := $(OBJECT_DIR)/fw.elf
TARGET_EXE := $(BIN_DIR)/fw
DEFAULT_OUTPUT := exe
REVISION := 0123abcde
FC_VER := 9.9.9
TARGET := SITL
OBJS := $(addprefix $(OBJECT_DIR)/,main.o util.o)

$(OBJECT_DIR)/%.o: %.c
\t@mkdir -p $(dir $@)
\t@echo "%% (optimised) $<" && $(CCACHE) gcc -MMD -MP -c -o $@ $(EXTRA_FLAGS) $<

-include $(OBJS:.o=.d)

$(TARGET_ELF): $(OBJS)
\t@echo "Linking fw"
\t@gcc -o $@ $^
\t@size $@

$(TARGET_EXE): $(TARGET_ELF)
\t@cp $< $@
"""

LINKER_TABLE = """\
Memory region         Used Size  Region Size  %age Used
        ITCM_RAM:       15416 B        16 KB     94.09%
      ITCM_FLASH:          0 GB        16 KB      0.00%
     ITCM_FLASH1:          0 GB       480 KB      0.00%
      AXIM_FLASH:         480 B        16 KB      2.93%
     AXIM_FLASH1:      349164 B       480 KB     71.04%
        DTCM_RAM:       33672 B        64 KB     51.38%
           SRAM1:       39092 B       176 KB     21.69%
       MEMORY_B1:          0 GB         0 GB
   text	   data	    bss	    dec	    hex	filename
 344092	   5552	  67208	 416852	  65c54	./obj/main/fw.elf
"""


@pytest.fixture
def fake_tree(tmp_path: Path) -> Path:
    tree = tmp_path / "tree"
    tree.mkdir()
    (tree / "Makefile").write_text(MAKEFILE)
    (tree / "main.c").write_text("int util(void);\nint main(void) { return util(); }\n")
    (tree / "util.c").write_text("int util(void) { return UTIL_VALUE; }\n")
    return tree


def command_for(
    tree: Path, tmp_path: Path, extra: str = "-DUTIL_VALUE=0", *, ccache: bool = False
) -> make.MakeCommand:
    """Make in TREE, objects in TMP_PATH/obj; with `ccache`, through a cache of its own in
    TMP_PATH/cache whose base directory is TMP_PATH, as wftool builds."""
    objects = tmp_path / "obj"
    hook = objects / "wftool.mk"
    make.write_hook(hook)
    variables = make.object_dir_variables(tree, objects) | {"EXTRA_FLAGS": extra}
    env = {}
    if ccache:
        variables["CCACHE"] = "ccache"
        env = {"CCACHE_DIR": str(tmp_path / "cache"), "CCACHE_BASEDIR": str(tmp_path),
               "CCACHE_NOHASHDIR": "true"}  # fmt: skip
    return make.MakeCommand(tree=tree, variables=variables, jobs=2, hook=hook, env=env)


def test_plan_run_and_noop(fake_tree, tmp_path):
    command = command_for(fake_tree, tmp_path)

    plan = make.plan(command)
    assert sorted(plan.units) == ["main.c", "util.c"]
    assert not plan.up_to_date
    assert plan.values["revision"] == "0123abcde"
    assert plan.values["version"] == "9.9.9"
    assert plan.values["exe"] == str(tmp_path / "obj" / "fw")

    run = make.run(command, tmp_path / "out" / "build.log", None, planned=len(plan.units))
    assert run.compiled == 2
    assert run.values == plan.values
    assert run.usage is not None and run.usage.flash_total is None
    assert (tmp_path / "obj" / "fw").is_file()
    assert "Linking fw" in (tmp_path / "out" / "build.log").read_text()

    assert make.plan(command).up_to_date


@pytest.mark.skipif(not shutil.which("ccache"), reason="needs ccache")
def test_a_changed_header_recompiles_its_units_whether_ccache_compiled_or_served_them(
    fake_tree, tmp_path
):
    """Make knows each object by the name its dependency file gives it, both for a unit
    ccache compiled (a miss: it rewrites an absolute `-o` below CCACHE_BASEDIR) and for one
    it served from its cache (a hit)."""
    (fake_tree / "util.c").write_text('#include "util.h"\nint util(void) { return UTIL; }\n')
    header = fake_tree / "util.h"
    command = command_for(fake_tree, tmp_path, "", ccache=True)
    for cache in ("compiled", "served"):  # the second time every unit is in the cache
        for stale in (tmp_path / "obj").glob("*.[od]"):
            stale.unlink()
        header.write_text("#define UTIL 0\n")
        assert make.run(command, tmp_path / "build.log").compiled == 2
        assert make.plan(command).up_to_date
        header.write_text("#define UTIL 1\n")
        assert make.plan(command).units == ["util.c"], cache


def test_failure_names_the_first_error_and_the_log(fake_tree, tmp_path, monkeypatch):
    (fake_tree / "util.c").write_text("int util(void)\n{\n    return missing_name;\n}\n")
    command = command_for(fake_tree, tmp_path)
    log = tmp_path / "out" / "build.log"
    monkeypatch.chdir(tmp_path)

    with pytest.raises(BuildError) as failure:
        make.run(command, log)

    message = str(failure.value)
    assert message.startswith(f"tree{os.sep}util.c:3: error: 'missing_name' undeclared")
    assert str(log) in message
    assert "missing_name" in log.read_text()


def test_make_that_cannot_start_is_reported(tmp_path):
    (tmp_path / "Makefile").write_text("$(error No TARGET identified)\n")
    with pytest.raises(BuildError, match="No TARGET identified"):
        make.plan(command_for(tmp_path, tmp_path))


def test_linker_memory_table_gives_flash_and_ram_use():
    usage = make.parse_usage(LINKER_TABLE.splitlines(), "512")
    assert usage == make.Usage(
        flash_bytes=480 + 349164,
        flash_total=512 * 1024,
        ram_bytes=15416 + 33672 + 39092,
        ram_total=(16 + 64 + 176) * 1024,
    )


def test_size_row_is_the_fallback():
    usage = make.parse_usage(LINKER_TABLE.splitlines()[-2:], None)
    assert usage == make.Usage(344092 + 5552, None, 5552 + 67208, None)
