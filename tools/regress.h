/* tools/regress.h — `ubake regress LEVEL`: the door-opening regression comparison (query vs
 * reference, each door closed and open, points on both sides). Part of the command-line
 * program: prints its table and errors itself; returns the exit status. argv holds the
 * arguments after "regress". */
#ifndef UBAKE_TOOLS_REGRESS_H
#define UBAKE_TOOLS_REGRESS_H

int ub_cli_regress(int argc, char **argv);

#endif
