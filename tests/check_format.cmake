# Fails, listing the files, if any C++ source differs from what .clang-format gives.
# cmake -DCLANG_FORMAT=... -DSOURCE_DIR=... -P check_format.cmake
file(GLOB_RECURSE sources RELATIVE ${SOURCE_DIR}
     ${SOURCE_DIR}/filters/*.[ch]pp ${SOURCE_DIR}/protocol/*.[ch]pp ${SOURCE_DIR}/formats/*.[ch]pp
     ${SOURCE_DIR}/sim/*.[ch]pp ${SOURCE_DIR}/runtime/*.[ch]pp ${SOURCE_DIR}/tests/*.[ch]pp ${SOURCE_DIR}/bench/*.[ch]pp)
execute_process(COMMAND ${CLANG_FORMAT} --dry-run -Werror ${sources}
                WORKING_DIRECTORY ${SOURCE_DIR} RESULT_VARIABLE status ERROR_VARIABLE errors)
if(NOT status EQUAL 0)
  string(REGEX MATCHALL "[^\n]*error: code should be clang-formatted" offending "${errors}")
  list(LENGTH offending count)
  message(FATAL_ERROR "${count} places differ from .clang-format (run: clang-format -i FILES):\n${offending}")
endif()
message(STATUS "every file follows .clang-format")
