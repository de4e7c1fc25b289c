#include "estimator/features/loam_features.h"
