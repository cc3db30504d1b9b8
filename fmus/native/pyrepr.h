/* Numbers written as Python's repr writes them, for the messages of the native FMUs (the
 * same text as their Python twins' messages: `T = 0.1 is not allowed ...`).
 *
 * Standalone: the C library only (no FMI, no model), used by native.c and the models. */
#ifndef DELAYCOMP_PYREPR_H
#define DELAYCOMP_PYREPR_H

#include <stddef.h>

/* The shortest decimal that reads back as v, in repr's form ("0.1", "1e-05", "1.0",
 * "inf", "nan"), in a value that lives on the caller's stack. */
typedef struct { char s[40]; } Num;
Num num(double v);

/* "[1.0, 2.0]" in a fixed buffer (nothing allocated: the messages of a step; a text
 * longer than TEXT_MAX - 1 ends in "..."). */
#define TEXT_MAX 4096
typedef struct { char s[TEXT_MAX]; } Text;
Text vector_text(const double *v, size_t n);

/* "[[1.0], [2.0]]" in a malloc'd string (NULL when out of memory): initialization only. */
char *matrix_text(const double *a, size_t rows, size_t cols);

#endif
