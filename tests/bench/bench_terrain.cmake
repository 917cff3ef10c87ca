# The terrain benchmark (tests/bench/bench_terrain.cpp); it times the whole `terrastride map`.
add_executable(bench_terrain bench_terrain.cpp)
target_link_libraries(bench_terrain PRIVATE terrastride::terrain benchmark::benchmark terrastride_warnings)
target_compile_definitions(bench_terrain PRIVATE TERRASTRIDE_SHARED_DIR="${TERRASTRIDE_SHARED_DIR}" TERRASTRIDE_BINARY="$<TARGET_FILE:terrastride>")
add_dependencies(bench_terrain terrastride)
