"""How the program's processes treat the cyclic garbage collector (``vgm_studio.processes``)."""

from __future__ import annotations

import gc
import subprocess
import sys
import weakref

from vgm_studio.processes import long_lived


class _Node:
    me: _Node


def test_long_lived_leaves_what_existed_before_to_after_the_block() -> None:
    gc.collect()
    node = _Node()
    node.me = node  # a cycle: only the collector frees it
    ref = weakref.ref(node)
    with long_lived():
        assert gc.get_freeze_count() > 0
        del node
        gc.collect()
        assert ref() is not None, "a full pass inside the block walked an older object"
        young = _Node()
        young.me = young
        young_ref = weakref.ref(young)
        del young
        gc.collect()
        assert young_ref() is None, "a cycle made inside the block was not collected"
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert ref() is None


def test_the_program_ends_without_a_last_full_pass() -> None:
    # The console script's ``run``: even on an error, the heap is frozen before the exit,
    # whose last collection would otherwise walk all of it.
    code = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print('frozen', gc.get_freeze_count()))\n"
        "sys.argv = ['vgm-studio', 'info', 'no-such.log']\n"
        "from vgm_studio.tools.cmd import run\n"
        "run()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 1
    assert "no-such.log" in done.stderr
    frozen = int(done.stdout.split("frozen")[1])
    assert frozen > 10_000
