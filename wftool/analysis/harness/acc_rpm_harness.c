/*
 * wftool's harness around the Weitflug accelerometer RPM filter
 * (src/main/flight/acc_rpm_filter.c of the patch series), compiled together
 * with that file and Betaflight's common/filter.c and common/maths.c, for the
 * host (a shared library loaded by wftool.analysis.harness) and for the
 * Cortex-M7 (an image executed by wftool.analysis.m7).
 *
 * Only plain entry points live here: the filter code itself is the firmware's,
 * called exactly as accRpmFilterApply() calls it.
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <stdint.h>

#include "platform.h"

#include "common/filter.h"
#include "common/vector.h"

#include "flight/acc_rpm_filter.h"

// settings[]: the accRpmFilterConfig_t fields as int32, in CLI units
enum {
    SETTING_HARMONICS,
    SETTING_WEIGHT_1,
    SETTING_WEIGHT_2,
    SETTING_WEIGHT_3,
    SETTING_MIN_HZ,
    SETTING_FADE_RANGE_HZ,
    SETTING_Q,
    SETTING_COUNT
};

#define COEFFICIENTS_PER_NOTCH 6  // b0, b1, b2, a1, a2, weight

unsigned accHarnessFilterSize(void)
{
    return sizeof(accRpmFilter_t);
}

unsigned accHarnessHarmonicsMax(void)
{
    return ACC_RPM_FILTER_HARMONICS_MAX;
}

// Set the filter up as accRpmFilterInit() does with bidirectional DShot; returns whether it is active.
int accHarnessSetup(accRpmFilter_t *filter, const int32_t *settings, unsigned sampleRateHz, int motorCount)
{
    accRpmFilterConfig_t config = {
        .acc_rpm_filter_harmonics = settings[SETTING_HARMONICS],
        .acc_rpm_filter_weights = { settings[SETTING_WEIGHT_1], settings[SETTING_WEIGHT_2], settings[SETTING_WEIGHT_3] },
        .acc_rpm_filter_min_hz = settings[SETTING_MIN_HZ],
        .acc_rpm_filter_fade_range_hz = settings[SETTING_FADE_RANGE_HZ],
        .acc_rpm_filter_q = settings[SETTING_Q],
    };
    accRpmFilterSetup(filter, &config, sampleRateHz, motorCount);
    return accRpmFilterIsActive(filter);
}

// One accelerometer sample, as accRpmFilterApply() handles it: new motor frequencies, then the notches.
void accHarnessStep(accRpmFilter_t *filter, const float *motorHz, float *xyz)
{
    vector3_t value = { .v = { xyz[0], xyz[1], xyz[2] } };
    if (accRpmFilterIsActive(filter)) {
        accRpmFilterSetMotorFrequencies(filter, motorHz);
        accRpmFilterProcess(filter, &value);
    }
    xyz[0] = value.x;
    xyz[1] = value.y;
    xyz[2] = value.z;
}

// The notch coefficients in use (axis 0; the other axes share them), motor-major, then harmonic:
// [motor][harmonic][b0, b1, b2, a1, a2, weight]; harmonics the filter skips (weight 0) read weight 0.
int accHarnessCoefficients(const accRpmFilter_t *filter, float *out)
{
    int count = 0;
    for (int motor = 0; motor < filter->motorCount; motor++) {
        for (int n = 0; n < filter->numHarmonics; n++) {
            const biquadFilter_t *notch = &filter->notch[0][motor][n];
            float *c = &out[count * COEFFICIENTS_PER_NOTCH];
            c[0] = notch->b0;
            c[1] = notch->b1;
            c[2] = notch->b2;
            c[3] = notch->a1;
            c[4] = notch->a2;
            c[5] = filter->weights[n] > 0.0f ? notch->weight : 0.0f;
            count++;
        }
    }
    return count;
}
