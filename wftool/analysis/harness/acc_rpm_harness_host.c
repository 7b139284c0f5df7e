/*
 * Host-only part of wftool's accelerometer RPM filter harness: whole signals
 * in one call, and the timing loops (CLOCK_MONOTONIC around a loop over all
 * samples, so the clock is read twice per loop and not per sample).
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "platform.h"

#include "common/filter.h"
#include "common/vector.h"

#include "flight/acc_rpm_filter.h"

void accHarnessStep(accRpmFilter_t *filter, const float *motorHz, float *xyz);

// samples: count x 3 floats, filtered in place; motorHz: count x motorCount floats
void accHarnessRun(accRpmFilter_t *filter, size_t count, int motorCount, const float *motorHz, float *samples)
{
    for (size_t i = 0; i < count; i++) {
        accHarnessStep(filter, &motorHz[i * motorCount], &samples[i * 3]);
    }
}

static double nowNs(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

// Wall time (ns) of accRpmFilterSetMotorFrequencies() over all samples' motor frequencies.
double accHarnessTimeUpdate(accRpmFilter_t *filter, size_t count, int motorCount, const float *motorHz)
{
    const double start = nowNs();
    for (size_t i = 0; i < count; i++) {
        accRpmFilterSetMotorFrequencies(filter, &motorHz[i * motorCount]);
    }
    return nowNs() - start;
}

// Wall time (ns) of accRpmFilterProcess() over count samples (count x 3 floats, filtered in place).
double accHarnessTimeProcess(accRpmFilter_t *filter, size_t count, float *samples)
{
    const double start = nowNs();
    for (size_t i = 0; i < count; i++) {
        accRpmFilterProcess(filter, (vector3_t *)&samples[i * 3]);
    }
    return nowNs() - start;
}

// Wall time (ns) of count calls of Betaflight's svfNotchApply() (the reference: one notch, one
// sample of one axis).
double accHarnessTimeNotch(size_t count, float *samples)
{
    svfNotchFilter_t notch;
    svfNotchInit(&notch, 100.0f, 0.001f, 5.0f);
    const double start = nowNs();
    for (size_t i = 0; i < count; i++) {
        samples[i] = svfNotchApply(&notch, samples[i]);
    }
    return nowNs() - start;
}
