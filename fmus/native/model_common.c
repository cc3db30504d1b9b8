/* The parameters and the flow of a user model, shared by its native plant and controller
 * (see model_common.h). */
#include <math.h>
#include <string.h>

#include "model_common.h"
#include "model.h"
#include "model_config.h"

void model_parameters(const Instance *c, double *p) {
    for (size_t i = 0; i < MODEL_NP; i++)
        p[i] = PARAM_VR[i] >= 0 ? c->d.real[PARAM_VR[i]] : NAN;
}

int model_check_numbers(Instance *c) {
    for (size_t i = 0; i + 1 < MODEL_NP; i++) {  /* p's last entry is T: not the model's */
        if (PARAM_VR[i] < 0) continue;
        double v = c->d.real[PARAM_VR[i]];
        if (!isfinite(v)) {
            log_error(c, "%s = %s is not allowed: must be a finite number",
                      VAR_NAME[PARAM_VR[i]], num(v).s);
            return -1;
        }
    }
    return 0;
}

#if NCHOICE > 0
int model_resolve_choices(Instance *c) {
    for (size_t s = 0; s < NCHOICE; s++)
        if (resolve_choice_index(c, CHOICE_NAME[s], CHOICE_VR[s], CHOICE_INDEX_VR[s],
                                 CHOICE_VALUES[s], CHOICE_COUNT[s]) != 0)
            return -1;
    return 0;
}

/* The order of delaycomp.fmu.translate: itertools.product over the names in sorted order,
 * the first name most significant. */
int model_branch(Instance *c, int *branch) {
    int b = 0;
    for (size_t s = 0; s < NCHOICE; s++) {
        const char *value = c->d.string[STRING_SLOT[CHOICE_VR[s]]];
        int pos = -1;
        for (int j = 0; j < CHOICE_COUNT[s]; j++)
            if (strcmp(value, CHOICE_VALUES[s][j]) == 0) pos = j;
        if (pos < 0) {
            char listed[STRING_MAX * 4];
            join_choices(CHOICE_VALUES[s], CHOICE_COUNT[s], listed, sizeof listed);
            log_error(c, "%s = '%s' is not allowed: must be one of %s", CHOICE_NAME[s], value,
                      listed);
            return -1;
        }
        b = b * CHOICE_COUNT[s] + pos;
    }
    *branch = b;
    return 0;
}
#else
int model_resolve_choices(Instance *c) {
    (void)c;
    return 0;
}

int model_branch(Instance *c, int *branch) {
    (void)c;
    *branch = 0;
    return 0;
}
#endif

int model_rhs(void *ctx, const double *x, double *dx) {
    const ModelRhs *r = ctx;
    return gen_f(r->branch, x, r->u, r->p, dx);
}
