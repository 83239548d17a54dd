"""`softcbf bench`: every selected safety filter over one fixed battery (docs/beyond-the-paper.md#filter-benchmark).

    softcbf bench --out DIR [--filters SPEC,SPEC,...] [--quick] [--cases NAME,...] [--mismatch-draws N] [--workers N]
                  [--falsify-budget N] [--resume | --overwrite]

Its rooms, each module's docstring the reference for its part:

| module      | what                                                                                           |
|-------------|------------------------------------------------------------------------------------------------|
| filters     | the filters under test: `--filters` specs, the default selection (the recommended filter and the baselines) |
| battery     | the battery's data file battery.toml (every case and setting): read, checked, its table in docs/results.md |
| cases       | the battery (`CASES`, from battery.toml), how each case runs, each filter's parameters per case, contact under error per filter and plant |
| figures     | a case's figures from its run folders: pooling, faults, steady force, nominal acceptance       |
| certified   | which coordinates of the worst-case search's box lie beyond what a filter certifies           |
| schema      | bench.json's fields and their check                                                            |
| tables      | bench.md and the words of the printed lines                                                    |
| plots       | plots/bench.png and plots/force_budget.png (import softcbf.bench.plots)                        |
| folder      | the bench folder: taken, locked, resumed, written                                              |
| runner      | `run_bench`: the cases, then each filter's worst case found, with progress                     |
| cli         | the command line                                                                               |

This package re-exports the names that tools, tests and docs use (`__all__`); the plots (matplotlib) load with
the first figure written, so that the bench's first progress line comes early.
"""

from softcbf.bench.cases import (CASES, EERG_PARAMS, EMULATOR_CONFIG, FORCE_TARGET_RATIO, PAPER_TUNINGS,
                                 PUSH_DURATION_S, PUSH_PLANTS, PUSH_PREFIX, PUSH_RATIOS, PUSHES, QUICK_DURATION_S,
                                 QUICK_PUSH_DURATION_S, THREE_SEGMENT_CASES, Case, RunOptions, arm_refusal,
                                 case_filter_params, mismatch_study, plant_parameters, push_cases, skip_key,
                                 BOX_PUSH, CONTACT_KEYS, FLEXURE_ASKED_N, PUSH_BOX_DRAWS, PUSH_BOX_FILES,
                                 QUICK_PUSH_BOX_DRAWS, contact_error_cases, contact_under_error, push_box_study)
from softcbf.bench.certified import beyond_certified
from softcbf.bench.cli import HELP, add_arguments, run_command
from softcbf.bench.figures import (ACCEPT_TOL_HPA, draw_figures, nominal_acceptance, pooled_figures, study_draws,
                                   study_figures)
from softcbf.bench.filters import DEFAULT_FILTERS, RECOMMENDED_FILTER, FilterSpec, parse_filters
from softcbf.bench.folder import BENCH_FILE, TABLE_FILE, is_bench_folder, prepare_bench_dir, stored_results, write_outputs
from softcbf.bench.runner import WORST_DIR, planned_cases, run_bench, worst_case_searches
from softcbf.bench.schema import (CALL_KEYS, RESULT_KEYS, ROW_SCHEMA, VERDICT_KEYS, VIOLATION_KEYS, WORST_KEYS,
                                  WORST_SCHEMA, check_bench_json)
from softcbf.bench.tables import (FORCE_PLOT_FILE, PLOT_FILE, PRINT_WIDTH, WIDER_BOX, contact_markdown, contact_text, fault_text,
                                  table_markdown, worst_case_text, worst_found_markdown)
from softcbf_mj.outputs.push_force import steady_force, steady_force_of_folder

__all__ = [
    "BOX_PUSH", "CONTACT_KEYS", "FLEXURE_ASKED_N", "PRINT_WIDTH", "PUSH_BOX_DRAWS", "PUSH_BOX_FILES",
    "QUICK_PUSH_BOX_DRAWS", "VIOLATION_KEYS", "contact_error_cases", "contact_markdown", "contact_text",
    "contact_under_error", "draw_figures", "push_box_study", "study_draws",
    "ACCEPT_TOL_HPA", "BENCH_FILE", "CALL_KEYS", "CASES", "DEFAULT_FILTERS", "EERG_PARAMS",
    "EMULATOR_CONFIG", "FORCE_PLOT_FILE", "FORCE_TARGET_RATIO", "HELP", "PAPER_TUNINGS", "PLOT_FILE",
    "PUSH_DURATION_S", "PUSH_PLANTS", "PUSH_PREFIX", "PUSH_RATIOS", "PUSHES", "QUICK_DURATION_S",
    "QUICK_PUSH_DURATION_S", "RECOMMENDED_FILTER", "RESULT_KEYS", "ROW_SCHEMA", "TABLE_FILE", "THREE_SEGMENT_CASES",
    "VERDICT_KEYS", "WIDER_BOX", "WORST_DIR", "WORST_KEYS", "WORST_SCHEMA", "Case", "FilterSpec", "RunOptions",
    "add_arguments", "arm_refusal", "beyond_certified", "case_filter_params", "check_bench_json", "fault_text",
    "is_bench_folder", "mismatch_study", "nominal_acceptance", "parse_filters", "planned_cases", "plant_parameters",
    "pooled_figures", "prepare_bench_dir", "push_cases", "run_bench", "run_command", "skip_key", "steady_force",
    "steady_force_of_folder", "stored_results", "study_figures", "table_markdown", "worst_case_searches",
    "worst_case_text", "worst_found_markdown", "write_outputs",
]
