#include "estimator/factors/lidar_factors.h"
