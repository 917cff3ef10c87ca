#include "terrastride/service/cli.hpp"

int main(int argc, char** argv) { return terrastride::service::run_cli(argc, argv); }
