#include "estimator/features/rail_extraction.h"
