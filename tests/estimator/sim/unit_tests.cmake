# Unit tests of the simulator's scenario parser, alignment, motion, sensor and corridor models:
# one binary, known answers with explicit tolerances. Included from this folder's CMakeLists.txt.
raillomer_add_test(test_sim_units
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/alignment_test.cc
    ${CMAKE_CURRENT_LIST_DIR}/motion_test.cc
    ${CMAKE_CURRENT_LIST_DIR}/scenario_test.cc
    ${CMAKE_CURRENT_LIST_DIR}/sensor_models_test.cc
    ${CMAKE_CURRENT_LIST_DIR}/world_test.cc
  DEPS raillomer_sim)
