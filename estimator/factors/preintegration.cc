#include "estimator/factors/preintegration.h"
