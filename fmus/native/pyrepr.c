/* Numbers written as Python's repr writes them (see pyrepr.h): the fewest significant
 * digits that read back exactly, positional from 1e-4 up to 1e16, exponent otherwise. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pyrepr.h"

/* "d.ddde+XX" with its last mantissa digit one up or one down, if that reads back as v
 * (printf rounds an exact decimal tie to even; the shortest repr may be the other side) */
static int nudge_last_digit(char *text, double v) {
    char *e = strchr(text, 'e');
    if (e == NULL || e == text) return 0;
    for (int dir = 1; dir >= -1; dir -= 2) {
        char trial[40];
        snprintf(trial, sizeof trial, "%s", text);
        char *d = trial + (e - text) - 1;
        if (*d == '.') d--;
        if (dir > 0 && *d == '9') continue;  /* would carry: not a tie neighbour here */
        if (dir < 0 && *d == '0') continue;
        *d = (char)(*d + dir);
        if (strtod(trial, NULL) == v) {
            memcpy(text, trial, strlen(trial) + 1);
            return 1;
        }
    }
    return 0;
}

Num num(double v) {
    Num n;
    if (isnan(v)) { snprintf(n.s, sizeof n.s, "nan"); return n; }
    if (isinf(v)) { snprintf(n.s, sizeof n.s, v > 0 ? "inf" : "-inf"); return n; }
    int p = 1;  /* the fewest significant digits that read back exactly */
    for (; p < 17; p++) {
        snprintf(n.s, sizeof n.s, "%.*e", p - 1, v);
        if (strtod(n.s, NULL) == v) break;
        if (nudge_last_digit(n.s, v)) break;  /* an exact tie rounded the other way */
    }
    if (p == 17) snprintf(n.s, sizeof n.s, "%.*e", p - 1, v);
    int exp10 = atoi(strchr(n.s, 'e') + 1);
    if (exp10 >= -4 && exp10 < 16) {  /* Python's repr: positional in this range */
        int decimals = p - 1 - exp10;
        snprintf(n.s, sizeof n.s, "%.*f", decimals > 0 ? decimals : 0, v);
        if (strchr(n.s, '.') == NULL) strcat(n.s, ".0");  /* Python writes 1.0, not 1 */
    }
    return n;
}

static int append(char **buf, size_t *len, size_t *cap, const char *text) {
    size_t add = strlen(text);
    if (*len + add + 1 > *cap) {
        size_t cap2 = (*cap + add + 1) * 2;
        char *b = realloc(*buf, cap2);
        if (b == NULL) return -1;
        *buf = b;
        *cap = cap2;
    }
    memcpy(*buf + *len, text, add + 1);
    *len += add;
    return 0;
}

char *matrix_text(const double *a, size_t rows, size_t cols) {
    char *buf = NULL;
    size_t len = 0, cap = 0;
    int bad = append(&buf, &len, &cap, rows > 1 || cols > 0 ? "[" : "");
    for (size_t i = 0; i < rows && !bad; i++) {
        bad |= append(&buf, &len, &cap, i ? ", [" : "[");
        for (size_t j = 0; j < cols && !bad; j++) {
            if (j) bad |= append(&buf, &len, &cap, ", ");
            bad |= append(&buf, &len, &cap, num(a[i * cols + j]).s);
        }
        bad |= append(&buf, &len, &cap, "]");
    }
    bad |= append(&buf, &len, &cap, "]");
    if (bad) { free(buf); return NULL; }
    return buf;
}

/* text += add, within TEXT_MAX (then cut, ending in "..."); -1 once cut */
static int append_fixed(Text *text, size_t *len, const char *add) {
    size_t n = strlen(add);
    if (*len + n + 1 > TEXT_MAX - 4) {
        memcpy(text->s + *len, "...", 4);
        *len += 3;
        return -1;
    }
    memcpy(text->s + *len, add, n + 1);
    *len += n;
    return 0;
}

Text vector_text(const double *v, size_t n) {
    Text text;
    size_t len = 0;
    int cut = append_fixed(&text, &len, "[");
    for (size_t j = 0; j < n && !cut; j++) {
        if (j) cut = append_fixed(&text, &len, ", ");
        if (!cut) cut = append_fixed(&text, &len, num(v[j]).s);
    }
    if (!cut) append_fixed(&text, &len, "]");
    return text;
}

