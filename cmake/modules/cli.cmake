# CLI: run configuration, run recording, evaluation, map export, reports and the
# run/compare/evaluate/export/inspect subcommands. Owned by helper "cli".
omnicml_add_library(omnicml_cli_support
  SOURCES src/svg_plot.cc src/report.cc src/evaluation.cc src/run_config.cc src/run_recorder.cc
          src/map_export.cc
  DEPS omnicml_engine omnicml_sim omnicml_logs omnicml_core nlohmann_json::nlohmann_json yaml-cpp
       Eigen3::Eigen ${OpenCV_LIBS})

omnicml_add_command(
  SOURCES apps/cmd_run.cc apps/cmd_compare.cc apps/cmd_evaluate.cc apps/cmd_export.cc apps/cmd_inspect.cc
  DEPS omnicml_cli_support)

omnicml_add_test(svg_plot_test SOURCES tests/svg_plot_test.cc DEPS omnicml_cli_support)
omnicml_add_test(evaluation_test SOURCES tests/evaluation_test.cc DEPS omnicml_cli_support)
omnicml_add_test(run_config_test SOURCES tests/run_config_test.cc DEPS omnicml_cli_support)
omnicml_add_test(cli_end_to_end_test SOURCES tests/cli_end_to_end_test.cc DEPS omnicml_cli_support)
if(TARGET cli_end_to_end_test AND TARGET omnicml_cli)
  add_dependencies(cli_end_to_end_test omnicml_cli)
endif()
