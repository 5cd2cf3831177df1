#!/bin/sh
# CXX_COMPILER_LAUNCHER of nvdb_syntax_check (CMakeLists.txt,
# NVDB_CHECK_VARIANTS): runs the compile command it is given, which has
# -fsyntax-only (the code is checked, templates instantiated, and no object
# written), then creates the empty object file that the build expects, so
# that the next build does not check the file again unless it changed.
"$@" || exit $?
out=
prev=
for arg in "$@"; do
  [ "$prev" = "-o" ] && out=$arg
  prev=$arg
done
[ -z "$out" ] || : > "$out"
