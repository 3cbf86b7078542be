"""Exit codes of the `lads` command line, one table for every command module.

0 success; EXIT_INCOMPLETE the job ran but its result is not clean (a build with failed items,
a tree that does not verify); EXIT_LADS_ERROR a LadsError (bad input, config or paths), with
its message on stderr.
"""

EXIT_INCOMPLETE = 1
EXIT_LADS_ERROR = 2
