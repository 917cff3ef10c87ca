# Planner scenario runner (not Google Benchmark: each row is a whole solve). Run from the build
# directory: ./tests/bench/bench_scenarios [--repeat 3] [--only pallet_15,flat_2.4s] [--json]
add_executable(bench_scenarios bench_scenarios.cpp)
target_link_libraries(bench_scenarios PRIVATE terrastride::planner terrastride::terrain
                      terrastride::collision
                      nlohmann_json::nlohmann_json terrastride_warnings)
# Per-kind Jacobian cost of one problem: ./tests/bench/bench_jacobian [--sets all]
add_executable(bench_jacobian bench_jacobian.cpp)
target_link_libraries(bench_jacobian PRIVATE terrastride::planner terrastride::terrain
                      terrastride_warnings)
