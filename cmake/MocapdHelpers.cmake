# Per-target build settings for mocapd's own code: language level, warnings,
# sanitizers and Eigen diagnostics. Third-party code never sees these flags.

function(mocapd_configure_target target)
  target_compile_features(${target} PUBLIC cxx_std_20)
  set_target_properties(${target} PROPERTIES CXX_EXTENSIONS OFF)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor)
  # GCC 12 reports false -Wrestrict positives inside libstdc++'s std::string operator+
  # at -O3 (GCC bug 105329); the warning is not about our code.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
    target_compile_options(${target} PRIVATE -Wno-restrict)
  endif()
  if(MOCAPD_WARNINGS_AS_ERRORS)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(MOCAPD_SANITIZE)
    target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
    # The sanitizers' instrumentation makes GCC report spurious -Wmaybe-uninitialized
    # inside Eigen's expression templates; the plain build keeps the warning.
    target_compile_options(${target} PRIVATE -Wno-maybe-uninitialized)
  endif()
  if(MOCAPD_BUILD_FUZZERS)
    # Coverage instrumentation for libFuzzer in everything the harnesses call.
    target_compile_options(${target} PRIVATE -fsanitize=fuzzer-no-link,address,undefined)
  endif()
  if(MOCAPD_CHECK_EIGEN_MALLOC)
    target_compile_definitions(${target} PUBLIC EIGEN_RUNTIME_NO_MALLOC)
  endif()
  if(MOCAPD_INIT_EIGEN_NAN)
    target_compile_definitions(${target} PUBLIC EIGEN_INITIALIZE_MATRICES_BY_NAN)
  endif()
endfunction()

# mocapd_add_library(name folder SOURCES...) creates mocapd_<name> and mocapd::<name>.
function(mocapd_add_library name)
  add_library(mocapd_${name} ${ARGN})
  add_library(mocapd::${name} ALIAS mocapd_${name})
  target_include_directories(mocapd_${name} PUBLIC ${PROJECT_SOURCE_DIR})
  mocapd_configure_target(mocapd_${name})
endfunction()
