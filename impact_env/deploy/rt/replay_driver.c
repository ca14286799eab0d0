/* A driver that replays readings recorded from the virtual rig (impact-env's parity tests write
 * them) and records the commands: the real-time loop exercised without hardware. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "impact_driver.h"

typedef struct {
    double *readings;  /* [n][4] */
    double *commands;  /* [n], NaN where no command was applied */
    int64_t n;
    FILE *out;
} replay_ctx;

static int replay_read(void *ctx, int64_t tick, impact_real r[IMPACT_N_READINGS])
{
    replay_ctx *c = (replay_ctx *)ctx;
    if (tick >= c->n) return 1;
    for (int k = 0; k < IMPACT_N_READINGS; k++) r[k] = (impact_real)c->readings[tick * 4 + k];
    return 0;
}

static int replay_apply(void *ctx, int64_t tick, impact_real command)
{
    replay_ctx *c = (replay_ctx *)ctx;
    if (tick < c->n) c->commands[tick] = (double)command;
    return 0;
}

static void replay_idle(void *ctx)
{
    (void)ctx;
}

int replay_driver_open(impact_driver *drv, const char *readings_path, const char *commands_path,
                       int64_t *n_ticks)
{
    replay_ctx *c = calloc(1, sizeof *c);  /* set-up time, not the loop: allocation is fine here */
    FILE *f = fopen(readings_path, "rb");
    if (!c || !f) {
        free(c);
        if (f) fclose(f);
        return -1;
    }
    fseek(f, 0, SEEK_END);
    long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    c->n = bytes / (long)(4 * sizeof(double));
    c->readings = malloc((size_t)c->n * 4 * sizeof(double));
    c->commands = malloc((size_t)c->n * sizeof(double));
    if (!c->readings || !c->commands || fread(c->readings, sizeof(double), (size_t)c->n * 4, f)
                                            != (size_t)c->n * 4) {
        fclose(f);
        free(c->readings);
        free(c->commands);
        free(c);
        return -1;
    }
    fclose(f);
    for (int64_t k = 0; k < c->n; k++) c->commands[k] = NAN;
    c->out = fopen(commands_path, "wb");
    if (!c->out) {
        free(c->readings);
        free(c->commands);
        free(c);
        return -1;
    }
    drv->ctx = c;
    drv->read = replay_read;
    drv->apply = replay_apply;
    drv->idle = replay_idle;
    *n_ticks = c->n;
    return 0;
}

void replay_driver_close(impact_driver *drv)
{
    replay_ctx *c = (replay_ctx *)drv->ctx;
    if (!c) return;
    fwrite(c->commands, sizeof(double), (size_t)c->n, c->out);
    fclose(c->out);
    free(c->readings);
    free(c->commands);
    free(c);
    drv->ctx = NULL;
}
