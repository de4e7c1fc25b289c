# Shared build settings for every RailLoMer target.

# raillomer_target_options(<target>): C++17, warnings, and the repository root on the include
# path so headers are included as "api/...", "estimator/...".
function(raillomer_target_options target)
  target_compile_features(${target} PUBLIC cxx_std_17)
  set_target_properties(${target} PROPERTIES CXX_EXTENSIONS OFF)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow
                                           -Wnon-virtual-dtor -Wno-unused-parameter)
  target_include_directories(${target} PUBLIC ${PROJECT_SOURCE_DIR})
endfunction()

# raillomer_add_library(<name> SOURCES ... DEPS ...): a static library with the house options.
function(raillomer_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  raillomer_target_options(${name})
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()

# raillomer_add_executable(<name> SOURCES ... DEPS ...): a program in build/bin.
function(raillomer_add_executable name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  raillomer_target_options(${name})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS})
endfunction()

# raillomer_add_test(<name> SOURCES ... DEPS ... [LABELS ...]): a GoogleTest binary whose cases
# are registered with ctest one by one. Slow tests carry the label "slow" and stay out of the
# default run (ctest -LE slow).
function(raillomer_add_test name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  raillomer_target_options(${name})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main)
  set_target_properties(${name} PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  # Where the sources (scripts, fixtures) and the programs are; $RAILLOMER_BIN (set by ctest)
  # and $RAILLOMER_SOURCE override them.
  target_compile_definitions(${name} PRIVATE RAILLOMER_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
                                             RAILLOMER_BIN_DIR="${CMAKE_BINARY_DIR}/bin")
  if(NOT ARG_LABELS)
    set(ARG_LABELS unit)
  endif()
  gtest_discover_tests(${name}
    TEST_PREFIX "${name}."
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}
    PROPERTIES LABELS "${ARG_LABELS}" ENVIRONMENT "RAILLOMER_BIN=${CMAKE_BINARY_DIR}/bin"
    DISCOVERY_MODE PRE_TEST)
endfunction()
