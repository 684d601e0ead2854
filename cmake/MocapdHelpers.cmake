# Per-target build settings for mocapd's own code: language level, warnings,
# sanitizers and Eigen diagnostics. Third-party code never sees these flags.

# The per-frame math is small fixed-size linear algebra; AVX2 + FMA cut its instruction
# count by about a quarter. The daemon is built where it runs, so "auto" enables them
# when this host can execute them, and keeps the compiler default otherwise.
if(MOCAPD_ARCH STREQUAL "auto")
  include(CheckCXXSourceRuns)
  set(CMAKE_REQUIRED_FLAGS "-march=x86-64-v3")
  check_cxx_source_runs("
    #include <immintrin.h>
    int main() {
      __m256d a = _mm256_set1_pd(1.0);
      a = _mm256_fmadd_pd(a, a, a);
      return _mm256_cvtsd_f64(a) == 2.0 ? 0 : 1;
    }" MOCAPD_HOST_RUNS_X86_64_V3)
  unset(CMAKE_REQUIRED_FLAGS)
  if(MOCAPD_HOST_RUNS_X86_64_V3)
    set(MOCAPD_MARCH "x86-64-v3")
  else()
    set(MOCAPD_MARCH "")
  endif()
else()
  set(MOCAPD_MARCH "${MOCAPD_ARCH}")
endif()
message(STATUS "mocapd: -march=${MOCAPD_MARCH}")

function(mocapd_configure_target target)
  target_compile_features(${target} PUBLIC cxx_std_20)
  set_target_properties(${target} PROPERTIES CXX_EXTENSIONS OFF)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor)
  if(MOCAPD_MARCH)
    # PUBLIC: Eigen's alignment must agree across every target that shares its types.
    target_compile_options(${target} PUBLIC -march=${MOCAPD_MARCH})
  endif()
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
    if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
      target_compile_options(${target} PRIVATE -Wno-maybe-uninitialized)
    endif()
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
