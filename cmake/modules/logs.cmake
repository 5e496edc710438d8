# Logs: the multi-day log format (reader, writer, validator) and the AntWorld importer.
omnicml_add_library(omnicml_logs
  SOURCES src/log_format.cc src/antworld.cc
  DEPS omnicml_core omnicml_unwrap yaml-cpp ${OpenCV_LIBS})
omnicml_add_test(logs_test
  SOURCES tests/log_format_test.cc tests/antworld_test.cc
  DEPS omnicml_logs)
omnicml_add_command(SOURCES apps/cmd_import.cc DEPS omnicml_logs)
