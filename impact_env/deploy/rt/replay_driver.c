/* A driver that replays readings recorded from the virtual rig (impact-env's parity tests write
 * them) and records the commands: a real-time loop exercised without hardware.  Used by the C
 * runtime (main.c: replay_driver_open) and by the target (impact_driver_open, loaded with
 * impact-env rig serve --driver replay_driver.so --driver-config "READINGS.f64;COMMANDS.f64").
 *
 * --driver-config options after the two paths (";"-separated, for tests of the loop's faults):
 *   read_delay_us=N   every read sleeps N us (a slow DAQ: the loop falls behind and skips ticks)
 *   stall=T:N         the read of tick T sleeps N us once per episode (one long stall)
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "impact_driver.h"

typedef struct {
    double *readings;  /* [n][4] */
    double *commands;  /* [n], NaN where no command was applied */
    int64_t n;
    FILE *out;
    int64_t read_delay_ns, stall_tick, stall_ns;
} replay_ctx;

static void sleep_ns(int64_t ns)
{
    struct timespec t;
    t.tv_sec = (time_t)(ns / 1000000000LL);
    t.tv_nsec = (long)(ns % 1000000000LL);
    while (nanosleep(&t, &t) != 0) {
    }
}

static int replay_read(void *ctx, int64_t tick, impact_real r[IMPACT_N_READINGS])
{
    replay_ctx *c = (replay_ctx *)ctx;
    if (c->read_delay_ns > 0) sleep_ns(c->read_delay_ns);
    if (tick == c->stall_tick && c->stall_ns > 0) sleep_ns(c->stall_ns);
    if (tick >= c->n) return 1;
    for (int k = 0; k < IMPACT_N_READINGS; k++) r[k] = (impact_real)c->readings[tick * 4 + k];
    return 0;
}

static int replay_apply(void *ctx, int64_t tick, impact_real command)
{
    replay_ctx *c = (replay_ctx *)ctx;
    if (tick >= 0 && tick < c->n) c->commands[tick] = (double)command;
    return 0;
}

static void write_commands(replay_ctx *c)
{
    if (!c->out) return;
    fseek(c->out, 0, SEEK_SET);
    fwrite(c->commands, sizeof(double), (size_t)c->n, c->out);
    fflush(c->out);
}

/* the episode is over: the commands so far go to the file (the target calls idle at every end) */
static void replay_idle(void *ctx)
{
    write_commands((replay_ctx *)ctx);
}

static int replay_arm(void *ctx, uint64_t seed)
{
    replay_ctx *c = (replay_ctx *)ctx;
    (void)seed;
    for (int64_t k = 0; k < c->n; k++) c->commands[k] = NAN;
    return 0;
}

static int replay_release(void *ctx)
{
    (void)ctx;
    return 0;
}

static void replay_free(replay_ctx *c)
{
    if (!c) return;
    if (c->out) fclose(c->out);
    free(c->readings);
    free(c->commands);
    free(c);
}

static void replay_close(void *ctx)
{
    replay_ctx *c = (replay_ctx *)ctx;
    write_commands(c);
    replay_free(c);
}

static replay_ctx *replay_load(const char *readings_path, const char *commands_path)
{
    replay_ctx *c = calloc(1, sizeof *c);  /* set-up time, not the loop: allocation is fine here */
    FILE *f = fopen(readings_path, "rb");
    if (!c || !f) {
        free(c);
        if (f) fclose(f);
        return NULL;
    }
    c->stall_tick = -1;
    fseek(f, 0, SEEK_END);
    long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    c->n = bytes / (long)(4 * sizeof(double));
    c->readings = malloc((size_t)(c->n > 0 ? c->n : 1) * 4 * sizeof(double));
    c->commands = malloc((size_t)(c->n > 0 ? c->n : 1) * sizeof(double));
    if (c->n < 1 || !c->readings || !c->commands
            || fread(c->readings, sizeof(double), (size_t)c->n * 4, f) != (size_t)c->n * 4) {
        fclose(f);
        replay_free(c);
        return NULL;
    }
    fclose(f);
    for (int64_t k = 0; k < c->n; k++) c->commands[k] = NAN;
    c->out = fopen(commands_path, "wb");
    if (!c->out) {
        replay_free(c);
        return NULL;
    }
    return c;
}

static void replay_fill(impact_driver *drv, replay_ctx *c)
{
    drv->ctx = c;
    drv->read = replay_read;
    drv->apply = replay_apply;
    drv->idle = replay_idle;
    drv->arm = replay_arm;
    drv->release = replay_release;
    drv->close = replay_close;
    drv->abi = IMPACT_DRIVER_ABI;
    drv->real_size = (uint32_t)sizeof(impact_real);
}

int replay_driver_open(impact_driver *drv, const char *readings_path, const char *commands_path,
                       int64_t *n_ticks)
{
    replay_ctx *c = replay_load(readings_path, commands_path);
    if (!c) return -1;
    replay_fill(drv, c);
    *n_ticks = c->n;
    return 0;
}

void replay_driver_close(impact_driver *drv)
{
    replay_ctx *c = (replay_ctx *)drv->ctx;
    if (!c) return;
    replay_close(c);
    drv->ctx = NULL;
}

int impact_driver_open(impact_driver *drv, const char *config)
{
    char buf[4096];
    if (!config || strlen(config) >= sizeof buf) return -2;
    strcpy(buf, config);
    char *save = NULL;
    char *readings = strtok_r(buf, ";", &save);
    char *commands = strtok_r(NULL, ";", &save);
    if (!readings || !commands) return -2;  /* expected "READINGS.f64;COMMANDS.f64[;options]" */
    replay_ctx *c = replay_load(readings, commands);
    if (!c) return -1;
    for (char *opt = strtok_r(NULL, ";", &save); opt; opt = strtok_r(NULL, ";", &save)) {
        long long a = 0, b = 0;
        if (sscanf(opt, "read_delay_us=%lld", &a) == 1) {
            c->read_delay_ns = a * 1000;
        } else if (sscanf(opt, "stall=%lld:%lld", &a, &b) == 2) {
            c->stall_tick = a;
            c->stall_ns = b * 1000;
        } else {
            replay_free(c);
            return -3;  /* an option it does not know */
        }
    }
    replay_fill(drv, c);
    return 0;
}
