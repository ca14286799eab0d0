"""``scripts/perf_kernels.py``'s parsing of perf's report and gdb's answers (the profiling itself
needs perf, gdb and a live process: a benchmark, run by hand)."""

from __future__ import annotations

import perf_kernels  # scripts/ is on the tests' path (pyproject's pythonpath)


def test_report_lines_give_samples_per_object_and_symbol():
    text = "\n".join([
        "# comment",
        "          1201  [JIT] tid 3787                      [.] 0x00007f541b183083          -      -   ",
        "            17  libm.so.6                           [.] __ieee754_pow_fma           -      -   ",
        "             3  libllvmlite.so                      [.] llvm::Foo::bar(int, int)    -      -   ",
        "             2  [JIT] tid 3787                      [.] 0x00007f541b183083          -      -   ",
        "",
    ])
    counts = perf_kernels.parse_report(text)
    assert counts[("[JIT] tid 3787", "0x00007f541b183083")] == 1203
    assert counts[("libm.so.6", "__ieee754_pow_fma")] == 17
    assert counts[("libllvmlite.so", "llvm::Foo::bar(int, int)")] == 3  # a symbol with spaces
    assert len(counts) == 3


def test_gdb_answers_name_numba_functions_by_their_python_path():
    mangled = ("_ZN10impact_env3sim4step8sim_stepB2v9B56c8tJTIeFIjxB2IKSgI4CrvSCKg1MMbCQQPKkLTj8gMFYBFOOlH"
               "7AIpoAExx5ArrayIdLi1E1C7mutable7alignedE + 1130 in section .ltext of <in-memory@0x55b2ff>")
    assert perf_kernels.function_name(mangled) == "impact_env::sim::step::sim_step"
    demangled = ("impact_env::plant::integrators::_dopri_step[abi:v100][abi:c8tJTIeFIjx](long long, double) "
                 "+ 590 in section .ltext of <in-memory@0x55b3006>")
    assert perf_kernels.function_name(demangled) == "impact_env::plant::integrators::_dopri_step"
    jit_line = "NRT_decref + 9 in section .ltext of <in-memory@0x55b2ff>"
    assert perf_kernels.function_name(jit_line) == "NRT_decref"
    assert perf_kernels.function_name("No symbol matches 0x7f00.") == "(unnamed JIT code)"
