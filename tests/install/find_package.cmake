# Installs the build into a scratch prefix, then configures, builds and runs the find_package
# example against it: `cmake --install` + find_package(evkit) work as the README says.
#   cmake -DBUILD_DIR=... -DSOURCE_DIR=... -DSCRATCH=... -P find_package.cmake
file(REMOVE_RECURSE ${SCRATCH})
file(MAKE_DIRECTORY ${SCRATCH})
function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "failed (${rc}): ${ARGN}\n${out}\n${err}")
  endif()
  set(last_output "${out}" PARENT_SCOPE)
endfunction()
run(${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${SCRATCH}/prefix)
run(${CMAKE_COMMAND} -S ${SOURCE_DIR}/examples/find_package -B ${SCRATCH}/build -G Ninja
    -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=${SCRATCH}/prefix)
run(${CMAKE_COMMAND} --build ${SCRATCH}/build)
run(${SCRATCH}/build/evkit_example ${SCRATCH})
if(NOT last_output MATCHES "read 50000 events from .*events.h5\nedi: 3 sharp frames of 346x260")
  message(FATAL_ERROR "unexpected output of the example:\n${last_output}")
endif()
message(STATUS "${last_output}")
file(REMOVE_RECURSE ${SCRATCH})
