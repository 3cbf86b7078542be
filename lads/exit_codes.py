"""Exit codes of the `lads` command line, one table for every command module.

0 success; EXIT_INCOMPLETE the job ran but its result is not clean (a build with failed items,
a tree that does not verify); EXIT_LADS_ERROR a LadsError (bad input, config or paths), with
its message on stderr; EXIT_INTERRUPTED a build stopped by Ctrl-C (SIGINT), the shell's own
code for it (128 + 2): the finished items are kept and the same command resumes.
"""

EXIT_INCOMPLETE = 1
EXIT_LADS_ERROR = 2
EXIT_INTERRUPTED = 130
