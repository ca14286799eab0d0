/*
 * The DAQ boundary of the real-time example (main.c): a driver is three function pointers over
 * its own context, so that the loop does not care whether it talks to a comedi device, a
 * vendor's C API or a file of recorded readings (replay_driver.c).
 *
 * Units and signs are those of impact_policy.h: readings in SI (accelerometer m/s^2 down
 * positive, force N compression positive, potentiometer m down positive, body-1 sensor m or
 * NaN); the command is dimensionless, 1 = IMPACT_COMMAND_SCALE_N newtons upwards.
 */
#ifndef IMPACT_DRIVER_H
#define IMPACT_DRIVER_H

#include <stdint.h>

#include "impact_policy.h"

typedef struct impact_driver {
    void *ctx;
    /* the readings of tick `tick` (sampled at the tick's start); 0 ok, 1 no more data, <0 fault */
    int (*read)(void *ctx, int64_t tick, impact_real readings[IMPACT_N_READINGS]);
    /* hold `command` on the output from now until the next call; 0 ok, <0 fault */
    int (*apply)(void *ctx, int64_t tick, impact_real command);
    /* the output at 0 (end, fault, signal) */
    void (*idle)(void *ctx);
} impact_driver;

/* replay_driver.c: readings from a file of float64 [n][4] (little-endian), commands to a file of
 * float64 [n] (NaN for ticks that were skipped). */
int replay_driver_open(impact_driver *drv, const char *readings_path, const char *commands_path,
                       int64_t *n_ticks);
void replay_driver_close(impact_driver *drv);

#endif
