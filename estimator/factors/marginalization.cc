#include "estimator/factors/marginalization.h"
