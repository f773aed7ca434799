# Installs the build into a scratch prefix and imports evkit from there alone (not the build tree):
# `cmake --install` puts a complete package (core, front, stubs, py.typed) where python3 finds it.
#   cmake -DBUILD_DIR=... -DPYTHON=... -DSCRATCH=... -DPACKAGE_DIR=... -P install.cmake
file(REMOVE_RECURSE ${SCRATCH})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${SCRATCH}
                RESULT_VARIABLE rc OUTPUT_QUIET ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install failed (${rc}): ${err}")
endif()
foreach(f __init__.py __init__.pyi py.typed)
  if(NOT EXISTS ${SCRATCH}/${PACKAGE_DIR}/evkit/${f})
    message(FATAL_ERROR "not installed: ${PACKAGE_DIR}/evkit/${f}")
  endif()
endforeach()
execute_process(
  COMMAND ${CMAKE_COMMAND} -E env PYTHONPATH=${SCRATCH}/${PACKAGE_DIR} PYTHONNOUSERSITE=1
          ${PYTHON} -c "import evkit, sys; assert evkit.__file__.startswith(sys.argv[1]), evkit.__file__; print(evkit.__version__, evkit.__file__)" ${SCRATCH}
  WORKING_DIRECTORY ${SCRATCH}  # not the build tree's python/, which holds a package evkit too
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "import evkit from the installed package failed (${rc}):\n${out}\n${err}")
endif()
message(STATUS "${out}")
file(REMOVE_RECURSE ${SCRATCH})
