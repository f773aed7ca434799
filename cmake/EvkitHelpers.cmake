# Small helpers so that a new library, test or benchmark is one line.

# Flags every evkit target gets.
function(evkit_target_defaults target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic)
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    # GCC 12 reports its own AVX-512 intrinsics (inlined from Eigen under -march=native) as
    # (maybe-)uninitialized: a known false positive that would break -Werror builds.
    target_compile_options(${target} PRIVATE -Wno-maybe-uninitialized -Wno-uninitialized)
  endif()
  if(EVKIT_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(EVKIT_NATIVE)
    target_compile_options(${target} PRIVATE -march=native)
  endif()
  if(EVKIT_FUZZ)
    target_compile_options(${target} PRIVATE -fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer
                                             -fno-sanitize-recover=undefined)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
  elseif(EVKIT_SANITIZE)
    target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer
                                             -fno-sanitize-recover=undefined)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
  endif()
endfunction()

# evkit_add_library(NAME SOURCES a.cc b.cc DEPS dep1 dep2 [PRIVATE_DEPS ...])
function(evkit_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} ${ARG_SOURCES})
  add_library(evkit::${name} ALIAS ${name})
  target_include_directories(${name} PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/include>
    $<INSTALL_INTERFACE:include>)
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  evkit_target_defaults(${name})
  # `cmake --install` puts the library and its headers where find_package(evkit) finds them.
  install(TARGETS ${name} EXPORT evkitTargets ARCHIVE DESTINATION lib LIBRARY DESTINATION lib)
  install(DIRECTORY include/ DESTINATION include)
endfunction()

# evkit_add_test(NAME SOURCES a_test.cc DEPS lib1 lib2 [COST N])
# COST: ctest starts the tests of higher cost first (a fresh build has no timings of its own), so
# that the minute-long tests do not start last and leave one core idle at the end of `ctest -j`.
function(evkit_add_test name)
  cmake_parse_arguments(ARG "" "COST" "SOURCES;DEPS" ${ARGN})
  if(NOT ARG_COST)
    set(ARG_COST 0)
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main)
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR}/tests)
  target_compile_definitions(${name} PRIVATE
    EVKIT_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    EVKIT_BINARY="$<TARGET_FILE:evkit>")
  evkit_target_defaults(${name})
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES TIMEOUT 300 COST ${ARG_COST})
endfunction()

# evkit_add_benchmark(NAME SOURCES a_bench.cc DEPS lib1)
function(evkit_add_benchmark name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} benchmark::benchmark)
  evkit_target_defaults(${name})
endfunction()
