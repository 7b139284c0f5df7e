/*
 * This file is part of wftool (Weitflug research firmware, based on Betaflight).
 *
 * wftool is free software. You can redistribute this software
 * and/or modify this software under the terms of the GNU General
 * Public License as published by the Free Software Foundation,
 * either version 3 of the License, or (at your option) any later
 * version.
 *
 * wftool is distributed in the hope that it will be useful,
 * but WITHOUT ANY WARRANTY; without even the implied warranty of
 * MERCHANTABILITY or FITNESS FOR A PARTICULAR PURPOSE.
 *
 * See the GNU General Public License for more details.
 *
 * You should have received a copy of the GNU General Public
 * License along with this software.
 *
 * If not, see <http://www.gnu.org/licenses/>.
 */

/*
 * SpeedyBee F7 V3 (STM32F722RET6, BMI270 IMU on SPI1).
 *
 * Board definition in the Betaflight 2026.6 "config.h" format, consumed by
 * mk/config.mk (FC_TARGET_MCU selects src/platform/STM32/target/STM32F722)
 * when building with CONFIG=SPEEDYBEEF7V3 CONFIG_DIR=<wftool>/targets.
 * Pin map from the board's public documentation / published resource list.
 *
 * Serial ports on this board:
 *   UART1  PA9 / PA10   free (HD VTX / MSP / FSP)
 *   UART2  PA2 / PA3    receiver (SBUS by default; PA3 doubles as PPM input)
 *   UART3  PB10 / PB11  free (GPS / FSP)
 *   UART4  -   / PA1    RX only, ESC telemetry
 *   UART6  PC6 / PC7    free
 */

#pragma once

#define FC_TARGET_MCU           STM32F722

#define BOARD_NAME              SPEEDYBEEF7V3
#define MANUFACTURER_ID         SPBE

// ---- sensors and on-board devices ----
#define USE_GYRO
#define USE_ACC
#define USE_ACCGYRO_BMI270

#define USE_BARO
#define USE_BARO_BMP280
#define USE_BARO_DPS310

#define USE_MAX7456
#define USE_SDCARD
#define USE_SDCARD_SPI

// ---- IMU: BMI270 on SPI1; the footprint has two chip-select / EXTI positions ----
#define GYRO_1_SPI_INSTANCE     SPI1
#define GYRO_1_CS_PIN           PB2
#define GYRO_1_EXTI_PIN         PC4
#define GYRO_1_ALIGN            CW270_DEG_FLIP  // pitch 180 deg, yaw 270 deg

#define GYRO_2_SPI_INSTANCE     SPI1
#define GYRO_2_CS_PIN           PC15
#define GYRO_2_EXTI_PIN         PC3
#define GYRO_2_ALIGN            CW0_DEG_FLIP    // _FLIP = pitch 180 deg (board-underside mounting)

// the populated position on production boards
#define DEFAULT_GYRO_TO_USE     GYRO_CONFIG_USE_GYRO_2

// ---- SPI buses ----
#define SPI1_SCK_PIN            PA5
#define SPI1_SDI_PIN            PA6
#define SPI1_SDO_PIN            PA7

#define SPI2_SCK_PIN            PB13
#define SPI2_SDI_PIN            PB14
#define SPI2_SDO_PIN            PB15

#define SPI3_SCK_PIN            PC10
#define SPI3_SDI_PIN            PC11
#define SPI3_SDO_PIN            PC12

// OSD (AT7456E) on SPI2
#define MAX7456_SPI_INSTANCE    SPI2
#define MAX7456_SPI_CS_PIN      PB12

// SD card (blackbox) on SPI3; the same CS is listed for the flash footprint
#define SDCARD_SPI_INSTANCE     SPI3
#define SDCARD_SPI_CS_PIN       PD2
#define FLASH_SPI_INSTANCE      SPI3
#define FLASH_CS_PIN            PD2
#define DEFAULT_BLACKBOX_DEVICE BLACKBOX_DEVICE_SDCARD

// ---- I2C: barometer / external magnetometer ----
#define I2C1_SCL_PIN            PB8
#define I2C1_SDA_PIN            PB9
#define BARO_I2C_INSTANCE       I2CDEV_1
#define MAG_I2C_INSTANCE        I2CDEV_1

// ---- UARTs ----
#define UART1_TX_PIN            PA9
#define UART1_RX_PIN            PA10
#define UART2_TX_PIN            PA2
#define UART2_RX_PIN            PA3
#define UART3_TX_PIN            PB10
#define UART3_RX_PIN            PB11
#define UART4_RX_PIN            PA1
#define UART6_TX_PIN            PC6
#define UART6_RX_PIN            PC7

#define SERIALRX_UART           SERIAL_PORT_USART2
#define SERIALRX_PROVIDER       SERIALRX_SBUS
#define ESC_SENSOR_UART         SERIAL_PORT_UART4
#define RX_PPM_PIN              PA3

// ---- motors (bidirectional DShot capable timers) and other timer pins ----
#define MOTOR1_PIN              PA15
#define MOTOR2_PIN              PB3
#define MOTOR3_PIN              PB4
#define MOTOR4_PIN              PB6
#define MOTOR5_PIN              PB7
#define MOTOR6_PIN              PB5
#define MOTOR7_PIN              PB0
#define MOTOR8_PIN              PB1
#define LED_STRIP_PIN           PC8
#define CAMERA_CONTROL_PIN      PA0

//                     index, pin, timer option, dma option
#define TIMER_PIN_MAPPING \
    TIMER_PIN_MAP( 0, PA15, 1,  0) /* TIM2 CH1, motor 1 */ \
    TIMER_PIN_MAP( 1, PB3 , 1,  0) /* TIM2 CH2, motor 2 */ \
    TIMER_PIN_MAP( 2, PB4 , 1,  0) /* TIM3 CH1, motor 3 */ \
    TIMER_PIN_MAP( 3, PB6 , 1,  0) /* TIM4 CH1, motor 4 */ \
    TIMER_PIN_MAP( 4, PB7 , 1,  0) /* TIM4 CH2, motor 5 */ \
    TIMER_PIN_MAP( 5, PB5 , 1,  0) /* TIM3 CH2, motor 6 */ \
    TIMER_PIN_MAP( 6, PB0 , 2,  0) /* TIM3 CH3, motor 7 */ \
    TIMER_PIN_MAP( 7, PB1 , 2,  0) /* TIM3 CH4, motor 8 */ \
    TIMER_PIN_MAP( 8, PC8 , 2,  0) /* TIM8 CH3, LED strip */ \
    TIMER_PIN_MAP( 9, PA3 , 3, -1) /* TIM9 CH2, PPM */ \
    TIMER_PIN_MAP(10, PA0 , 2,  0) /* TIM5 CH1, camera control */

#define DEFAULT_DSHOT_BURST     DSHOT_DMAR_ON

#define DEFAULT_FEATURES        (FEATURE_OSD | FEATURE_TELEMETRY)

// ---- DMA ----
#define SPI3_TX_DMA_OPT         0
#define ADC1_DMA_OPT            1

// ---- ADC: battery voltage / current / RSSI ----
#define ADC_VBAT_PIN            PC2
#define ADC_CURR_PIN            PC1
#define ADC_RSSI_PIN            PC0
#define DEFAULT_VOLTAGE_METER_SOURCE VOLTAGE_METER_ADC
#define DEFAULT_VOLTAGE_METER_SCALE  110
#define DEFAULT_CURRENT_METER_SOURCE CURRENT_METER_ADC
#define DEFAULT_CURRENT_METER_SCALE  490

// ---- misc I/O ----
#define BEEPER_PIN              PC13
#define BEEPER_INVERTED
#define LED0_PIN                PA14
#define LED1_PIN                PA13

// PINIO1 switches the VTX / camera power rail (output, active high)
#define PINIO1_PIN              PC9
#define PINIO1_CONFIG           129
#define PINIO1_BOX              0
