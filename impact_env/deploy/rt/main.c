/*
 * A real-time Linux loop around impact_step: 10 kHz (IMPACT_CONTROL_RATE_HZ) on absolute
 * deadlines (clock_nanosleep TIMER_ABSTIME on CLOCK_MONOTONIC, so that sleep overshoot never
 * accumulates), under SCHED_FIFO with locked memory where the process may (root or
 * CAP_SYS_NICE; otherwise it says so and runs as an ordinary thread).
 *
 *   impact_rt READINGS.f64 COMMANDS.f64 [--no-sleep]
 *
 * reads the replay driver's recorded readings, runs one episode, writes the commands, and prints
 * tick lateness percentiles (p50, p99, p99.9, max, in us) and the overruns: a tick that starts a
 * period or more late skips the ticks that cannot run on time (the DAC holds the last command;
 * their command slots stay NaN), as the Python target does.  --no-sleep runs the ticks back to
 * back (a parity run: commands then depend on the readings only).
 *
 * To drive a rig, replace replay_driver_open with a driver of your DAQ (impact_driver.h): e.g.
 * comedi_data_read/comedi_data_write on a comedi device, or the vendor's C API, converting
 * volts to SI with the calibration constants of the scene (docs/rig/wiring.md).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "impact_driver.h"
#include "impact_policy.h"

#define NS_PER_S 1000000000LL

static int64_t ts_ns(const struct timespec *t)
{
    return (int64_t)t->tv_sec * NS_PER_S + t->tv_nsec;
}

static struct timespec ns_ts(int64_t ns)
{
    struct timespec t;
    t.tv_sec = (time_t)(ns / NS_PER_S);
    t.tv_nsec = (long)(ns % NS_PER_S);
    return t;
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

static double pct(const int64_t *sorted, int64_t n, double p)
{
    if (n == 0) return 0.0;
    int64_t k = (int64_t)(p / 100.0 * (double)(n - 1) + 0.5);
    return (double)sorted[k] / 1e3;
}

static impact_state state;  /* static: a 10 kHz loop allocates nothing, and the state is large */

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s READINGS.f64 COMMANDS.f64 [--no-sleep]\n", argv[0]);
        return 2;
    }
    int pace = !(argc > 3 && strcmp(argv[3], "--no-sleep") == 0);
    impact_driver drv;
    int64_t n = 0;
    if (replay_driver_open(&drv, argv[1], argv[2], &n) != 0 || n < 1) {
        fprintf(stderr, "cannot open the readings %s or the output %s\n", argv[1], argv[2]);
        return 2;
    }
    struct sched_param sp = {.sched_priority = 80};
    int rt = pace && sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    if (rt) mlockall(MCL_CURRENT | MCL_FUTURE);
    if (pace && !rt)
        fprintf(stderr, "impact_rt: no SCHED_FIFO (%s): running as an ordinary thread\n", strerror(errno));
    int64_t *late = calloc((size_t)n, sizeof *late);
    if (!late) return 2;
    impact_init(&state);
    impact_reset(&state);
    const int64_t period = (int64_t)llround(1e9 / IMPACT_CONTROL_RATE_HZ);
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    int64_t t0 = ts_ns(&now) + period;  /* tick 0 is due one period from now */
    int64_t ticks_run = 0, overruns = 0, skipped = 0;
    uint32_t status_or = 0;
    impact_real readings[IMPACT_N_READINGS];
    for (int64_t m = 0; m < n;) {
        int64_t lateness = 0;
        if (pace) {
            struct timespec dl = ns_ts(t0 + m * period);
            while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &dl, NULL) == EINTR) {
            }
            clock_gettime(CLOCK_MONOTONIC, &now);
            lateness = ts_ns(&now) - (t0 + m * period);
            if (lateness >= period) {  /* an overrun: the ticks that cannot run on time pass */
                int64_t k = lateness / period;
                if (m + k >= n) k = n - m;
                m += k;
                skipped += k;
                overruns++;
                if (m >= n) break;
                lateness -= k * period;
            }
        }
        if (drv.read(drv.ctx, m, readings) != 0) break;
        impact_real command, force;
        status_or |= impact_step(&state, readings, &command, &force);
        drv.apply(drv.ctx, m, command);
        late[ticks_run++] = lateness;
        m++;
    }
    drv.idle(drv.ctx);
    replay_driver_close(&drv);
    qsort(late, (size_t)ticks_run, sizeof *late, cmp_i64);
    printf("impact_rt: %lld ticks run, %lld skipped in %lld overruns, %s, SCHED_FIFO %s\n",
           (long long)ticks_run, (long long)skipped, (long long)overruns, pace ? "paced" : "back to back",
           rt ? "on" : "off");
    printf("impact_rt: lateness us p50 %.1f p99 %.1f p99.9 %.1f max %.1f; status bits seen 0x%x\n",
           pct(late, ticks_run, 50.0), pct(late, ticks_run, 99.0), pct(late, ticks_run, 99.9),
           ticks_run ? (double)late[ticks_run - 1] / 1e3 : 0.0, (unsigned)status_or);
    free(late);
    return 0;
}
