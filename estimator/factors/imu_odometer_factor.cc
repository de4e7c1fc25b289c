#include "estimator/factors/imu_odometer_factor.h"
