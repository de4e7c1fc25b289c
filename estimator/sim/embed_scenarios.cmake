# Writes a C++ source holding every scenarios/*.yaml as a string, so raillomer-sim finds its
# built-in scenarios wherever it runs. Called at configure time from estimator/sim/CMakeLists.txt.
function(raillomer_embed_scenarios dir output)
  file(GLOB files CONFIGURE_DEPENDS "${dir}/*.yaml")
  list(SORT files)
  set(body "")
  foreach(file ${files})
    get_filename_component(name "${file}" NAME_WE)
    file(READ "${file}" text)
    string(APPEND body "      {\"${name}\", R\"raillomer_yaml(${text})raillomer_yaml\"},\n")
  endforeach()
  file(WRITE "${output}.new"
"// Generated from estimator/sim/scenarios/*.yaml by embed_scenarios.cmake. Do not edit.
#include \"estimator/sim/builtin_scenarios.h\"

namespace raillomer::sim {

const std::vector<BuiltinScenario>& BuiltinScenarios() {
  static const std::vector<BuiltinScenario> scenarios = {
${body}  };
  return scenarios;
}

}  // namespace raillomer::sim
")
  file(COPY_FILE "${output}.new" "${output}" ONLY_IF_DIFFERENT)
  file(REMOVE "${output}.new")
endfunction()
