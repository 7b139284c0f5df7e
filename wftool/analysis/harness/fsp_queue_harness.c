/*
 * wftool's harness around the FSP timed-command queue (src/main/io/fsp_queue.c of the
 * patch series), compiled with the sources its unit test compiles (the queue, the
 * freshness gate io/fsp_command.c, the codec, the MSP receiver rx/msp.c) for the
 * Cortex-M7 (an image executed by wftool.analysis.m7).
 *
 * The queue, the gate and the channel map live here, as io/fsp.c keeps them; the PID
 * loop's work is queueHarnessPidLoop(), which does what fspApplyTimedCommands() does
 * (without its check that an FSP port is open), so its cost is the loop's. The rest
 * prepares states to measure it in.
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "platform.h"

#include "fc/rc_modes.h"

#include "io/fsp_codec.h"
#include "io/fsp_command.h"
#include "io/fsp_queue.h"

#include "rx/rx.h"

#define HARNESS_TIMEOUT_US  50000  // timedcost.TIMEOUT_US

// what the firmware around the queue provides
rxRuntimeState_t rxRuntimeState;
static uint32_t harnessMs;

uint32_t millis(void)
{
    return harnessMs;
}

uint32_t micros(void)  // rx/msp.c stamps the MSP receiver's frames with it (Betaflight 2026.6)
{
    return harnessMs * 1000;
}

bool IS_RC_MODE_ACTIVE(boxId_e boxId)
{
    UNUSED(boxId);
    return false;
}

fspQueue_t harnessQueue;
fspCommandGate_t harnessGate;
uint8_t harnessRcmap[RX_MAPPABLE_CHANNEL_COUNT] = { 0, 1, 3, 2, 4, 5, 6, 7 };  // AETR1234
fspCommand_t harnessCommandBuf;     // a decoded command, for a measured fspQueueTake()
uint8_t harnessScratch[64];         // a report's wire bytes

static fspCommand_t harnessCommand(uint32_t seq, uint32_t atUs, bool timed)
{
    fspCommand_t cmd;
    memset(&cmd, 0, sizeof(cmd));
    cmd.seq = seq;
    for (unsigned i = 0; i < FSP_RC_COUNT; i++) {
        cmd.rc[i] = (int16_t)(1000 + 100 * i + seq % 100);
    }
    cmd.timed = timed;
    cmd.atUs = atUs;
    return cmd;
}

// A live uplink at nowUs (two immediate commands handed over), an empty queue.
void queueHarnessSetup(uint32_t nowUs)
{
    fspCommandGateInit(&harnessGate, HARNESS_TIMEOUT_US);
    fspQueueInit(&harnessQueue);
    for (uint32_t seq = 1; seq <= 2; seq++) {
        const fspCommand_t cmd = harnessCommand(seq, 0, false);
        fspCommandGateAdmit(&harnessGate, &cmd, nowUs);
    }
    fspCommandGateTakeEffect(&harnessGate, nowUs);
    const fspCommand_t cmd = harnessCommand(2, 0, false);
    fspCommandHandOver(&cmd, harnessRcmap);
}

// The FSP task decodes timed command `seq` at nowUs, due at atUs, into harnessCommandBuf
// and admits it (fresh: 1). fspQueueTake() then takes it into the queue.
int queueHarnessDecode(uint32_t seq, uint32_t atUs, uint32_t nowUs)
{
    harnessCommandBuf = harnessCommand(seq, atUs, true);
    return fspCommandGateAdmit(&harnessGate, &harnessCommandBuf, nowUs) == FSP_COMMAND_FRESH;
}

// Both, as the FSP task does; returns the outcome so far (-1: not fresh).
int queueHarnessTake(uint32_t seq, uint32_t atUs, uint32_t nowUs)
{
    if (!queueHarnessDecode(seq, atUs, nowUs)) {
        return -1;
    }
    return fspQueueTake(&harnessQueue, &harnessCommandBuf, nowUs, harnessGate.timeoutUs);
}

// The PID loop's work at an iteration at nowUs, as fspApplyTimedCommands() does it.
void queueHarnessPidLoop(uint32_t nowUs)
{
    if (fspQueueIsDue(&harnessQueue, nowUs)) {
        fspQueueApplyDue(&harnessQueue, &harnessGate, nowUs, harnessRcmap);
    }
}

// rxFrameCheck()'s every call with the MSP receiver: the receiver's signal delay.
int queueHarnessSignalDelay(void)
{
    return fspCommandGateSignalDelayUs(&harnessGate);
}

unsigned queueHarnessQueueSize(void)
{
    return sizeof(fspQueue_t);
}

unsigned queueHarnessQueued(void)
{
    return harnessQueue.count;
}

// The FSP task sends the oldest report; returns its outcome (-1: none).
int queueHarnessPopReport(void)
{
    fspCommandReport_t report;
    return fspQueuePopReport(&harnessQueue, &report) ? report.outcome : -1;
}

// A report's wire bytes as the FSP task encodes them (its cost per report, besides the UART).
unsigned queueHarnessEncodeReport(uint8_t *wire)
{
    static const fspCommandReport_t report = { 42, 123456, 5000000, 5000062, 0, 1, { 1, 0, 0, 0, 0, 0 } };
    uint8_t packet[FSP_COMMAND_REPORT_PACKET_SIZE];
    return fspFramePacket(wire, packet, fspEncodeCommandReport(packet, &report));
}
