#include "estimator/preprocess/filters.h"
