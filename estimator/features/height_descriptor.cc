#include "estimator/features/height_descriptor.h"
